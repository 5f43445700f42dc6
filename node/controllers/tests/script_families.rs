//! The families zmotor drives with its own scripts (`launch/scripts/`), each against its
//! emulator (written from the vendor's documents, apart from the script) in virtual time:
//! motion through the record's commands, the bytes the EPICS driver sends where the script
//! follows it, comm loss, replies in pieces, and no command sequence that makes a line the
//! controller cannot read.

mod common;

use common::{bring_up, go, run_until_done, script_loopback, script_source, written_since};
use proptest::prelude::*;
use std::time::Duration;
use zmotor_controllers::{ControllerEvent, Loopback, MacroValue};
use zmotor_emulators::{Faults, Model};
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

const TICK: Duration = Duration::from_millis(20);

/// A family: its script, its emulator, the macros its ready launch file gives, the two channels
/// (a script's AXIS) the tests drive.
struct Family {
    script: &'static str,
    model: Model,
    macros: &'static [(&'static str, &'static str)],
    channels: [usize; 2],
}

const KOHZU: Family =
    Family { script: "launch/scripts/kohzu_sc.lua", model: Model::KohzuSc, macros: &[], channels: [0, 1] };
const PICOMOTOR: Family =
    Family { script: "launch/scripts/newfocus_8742.lua", model: Model::NewFocus8742, macros: &[], channels: [0, 1] };
const PIEZO: Family =
    Family { script: "launch/scripts/piezojena_nv40.lua", model: Model::PiezojenaNv40, macros: &[], channels: [0, 1] };
const MICRONIX: Family =
    Family { script: "launch/scripts/micronix_mmc.lua", model: Model::MicronixMmc, macros: &[], channels: [0, 1] };
/// Node numbers 1 and 2 (0 reaches every drive on the line).
const FAULHABER: Family =
    Family { script: "launch/scripts/faulhaber_mc.lua", model: Model::FaulhaberMc, macros: &[], channels: [1, 2] };

impl Family {
    fn loopback(&self, faults: Faults) -> Loopback {
        let channels = &self.channels;
        let macros: Vec<(&str, MacroValue)> =
            self.macros.iter().map(|(name, value)| (*name, MacroValue::Text((*value).into()))).collect();
        let source = script_source(self.script, "ctl", &macros);
        script_loopback(&source, self.model, channels, faults)
    }

    fn up(&self) -> Loopback {
        let mut lb = self.loopback(Faults::default());
        bring_up(&mut lb);
        lb
    }
}

fn stop(lb: &mut Loopback, channel: usize) -> zmotor_core::DeviceStatus {
    lb.command(channel, &DriverCommand::Stop { acceleration: 50_000.0 });
    *run_until_done(lb, channel, TICK, Duration::from_secs(5)).last().expect("done")
}

/// A jog at `speed` steps/s (negative: down) runs until stopped, and stops soon after.
fn a_jog_runs_until_stopped(family: &Family, channel: usize, speed: f64) {
    let mut lb = family.up();
    let jog = DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: speed, acceleration: 50_000.0 };
    lb.command(channel, &jog);
    lb.run_for(Duration::from_secs(1));
    let status = common::last_status(&lb.take_events(), channel);
    assert_eq!(status.msta & (msta::DONE | msta::MOVING), msta::MOVING, "{status:?}");
    assert!(status.position.abs() > speed.abs() * 0.4, "{status:?}");
    let stopped = stop(&mut lb, channel);
    assert!(stopped.position.abs() < speed.abs() * 1.6, "stopped soon after the stop: {stopped:?}");
}

fn a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing(
    family: &Family,
    is_move: impl Fn(&str) -> bool,
    is_read: impl Fn(&str) -> bool,
) {
    let mut lb = family.up();
    let channel = family.channels[1];
    common::a_move_goes_once_and_a_new_connection_only_reads(&mut lb, channel, common::text, is_move, is_read);
}

/// The statuses of `common::statuses_of_a_script_on` with replies whole, checked to be the same
/// with replies split at every byte.
fn statuses_whole_and_in_pieces(family: &Family) -> [Vec<zmotor_core::DeviceStatus>; 2] {
    let statuses = |chunk| {
        common::statuses_of_a_script_on(family.loopback(Faults::default()).with_chunks(chunk), &family.channels)
    };
    let whole = statuses(usize::MAX);
    assert_eq!(statuses(1), whole);
    whole
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]
    #[test]
    fn no_sequence_of_record_commands_makes_a_malformed_line_in_any_family(
        family in 0usize..5,
        commands in proptest::collection::vec((0usize..2, common::command(), 0u64..300), 1..10)
    ) {
        let family = [&KOHZU, &MICRONIX, &PICOMOTOR, &PIEZO, &FAULHABER][family];
        let lb = family.loopback(Faults::default());
        common::no_malformed_frames_on(lb, &family.channels, common::Start::AsPoweredUp, &commands);
    }
}

fn no_failed_exchange(events: &[ControllerEvent]) {
    assert!(!events.iter().any(|e| matches!(e, ControllerEvent::Failed { .. })), "{events:?}");
}

/// A move at `max_velocity` steps/s, which the controller on `channel` cannot take: the script
/// refuses it (its error names each of `says`), the channel shows a problem, and no line
/// containing `command` is written.
fn a_speed_is_refused_unsent(lb: &mut Loopback, channel: usize, max_velocity: f64, says: &[&str], command: &str) {
    let from = lb.written().len();
    let fast_or_slow =
        DriverCommand::Move { position: 100.0, relative: false, min_velocity: 0.0, max_velocity, acceleration: 1e5 };
    lb.command(channel, &fast_or_slow);
    lb.run_for(Duration::from_millis(500));
    let events = lb.take_events();
    let errors = common::controller_errors(&events);
    let said = |(c, _, m): &(Option<usize>, String, String)| *c == Some(channel) && says.iter().all(|s| m.contains(s));
    assert!(errors.iter().any(said), "{events:?}");
    assert_ne!(common::last_status(&events, channel).msta & msta::PROBLEM, 0);
    assert!(!written_since(lb, from).iter().any(|l| l.contains(command)), "nothing sent");
}

mod kohzu {
    use super::*;

    #[test]
    fn a_move_sets_the_speeds_then_moves_as_motor_kohzu_does_and_arrives() {
        let mut lb = KOHZU.up();
        no_failed_exchange(&lb.take_events());
        let from = lb.written().len();
        common::a_move_arrives_where_asked_and_a_relative_one_from_there(&mut lb, 1, go);
        let sent = written_since(&lb, from);
        assert_eq!(sent[..2], ["\x02ASI2/1/20000/10/10/0/0/0/0/0/0/0/0/0\r\n", "\x02APS2/2/0/0/12345/0/0/1\r\n"]);
        assert!(sent.contains(&"\x02RPS2/2/0/0/-2345/0/0/1\r\n".to_string()), "{sent:?}");
    }

    #[test]
    fn a_jog_runs_until_stopped_and_the_stop_is_stp() {
        super::a_jog_runs_until_stopped(&KOHZU, 0, -5000.0);
    }

    #[test]
    fn an_origin_search_ends_at_zero_on_the_origin_switch() {
        let mut lb = KOHZU.up();
        lb.command(0, &go(30_000.0, false));
        run_until_done(&mut lb, 0, TICK, Duration::from_secs(5));
        let from = lb.written().len();
        let home = DriverCommand::Home { forward: false, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 2e5 };
        lb.command(0, &home);
        let homed = *run_until_done(&mut lb, 0, TICK, Duration::from_secs(20)).last().expect("done");
        assert_eq!(homed.position, 0.0, "{homed:?}");
        assert!(written_since(&lb, from).contains(&"\x02ORG1/2/0/0/3/1\r\n".to_string()));
    }

    #[test]
    fn a_speed_beyond_the_controller_is_refused_not_clamped() {
        let mut lb = KOHZU.up();
        a_speed_is_refused_unsent(&mut lb, 0, 5e6, &["kohzu_sc.lua:", "4095500"], "APS");
    }

    #[test]
    fn replies_split_at_every_byte_give_the_same_statuses() {
        common::replies_in_pieces_give_the_same_statuses_on(
            |chunk| KOHZU.loopback(Faults::default()).with_chunks(chunk),
            &KOHZU.channels,
        );
    }

    #[test]
    fn a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing() {
        let reads = |l: &str| ["STR", "RDP", "RSY"].iter().any(|q| l.starts_with(&format!("\x02{q}")));
        super::a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing(
            &KOHZU,
            |l| l.contains("APS"),
            reads,
        );
    }
}

mod micronix {
    use super::*;

    #[test]
    fn a_move_sets_speeds_in_millimetres_then_moves_as_motor_micronix_does_and_arrives() {
        let mut lb = MICRONIX.up();
        no_failed_exchange(&lb.take_events());
        let from = lb.written().len();
        common::a_move_arrives_where_asked_and_a_relative_one_from_there(&mut lb, 1, go);
        let sent = written_since(&lb, from);
        assert_eq!(sent[0], "2VEL0.020\r2ACC0.200\r2DEC0.200\r2MVA0.012345\r", "{sent:?}");
        assert!(sent.iter().any(|l| l.ends_with("2MVR-0.002345\r")), "{sent:?}");
    }

    #[test]
    fn a_jog_runs_until_stopped() {
        super::a_jog_runs_until_stopped(&MICRONIX, 0, -5000.0);
    }

    #[test]
    fn a_home_search_ends_at_zero() {
        let mut lb = MICRONIX.up();
        lb.command(0, &go(30_000.0, false));
        run_until_done(&mut lb, 0, TICK, Duration::from_secs(5));
        let home = DriverCommand::Home { forward: false, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 2e5 };
        lb.command(0, &home);
        let homed = *run_until_done(&mut lb, 0, TICK, Duration::from_secs(20)).last().expect("done");
        assert_eq!((homed.position, homed.msta & msta::HOMED), (0.0, msta::HOMED), "{homed:?}");
    }

    #[test]
    fn only_position_zero_is_set_and_another_is_refused() {
        let mut lb = MICRONIX.up();
        lb.command(0, &go(1000.0, false));
        run_until_done(&mut lb, 0, TICK, Duration::from_secs(5));
        let from = lb.written().len();
        lb.command(0, &DriverCommand::SetPosition { position: 5.0 });
        lb.run_for(Duration::from_millis(300));
        let errors = common::controller_errors(&lb.take_events());
        assert!(errors.iter().any(|(_, _, m)| m.contains("only position 0")), "{errors:?}");
        assert!(!written_since(&lb, from).iter().any(|l| l.contains("ZRO")));
        lb.command(0, &DriverCommand::SetPosition { position: 0.0 });
        lb.run_for(Duration::from_millis(1500));
        assert_eq!(common::last_status(&lb.take_events(), 0).position, 0.0);
    }

    #[test]
    fn a_speed_or_acceleration_below_the_controllers_three_decimals_is_refused_unsent() {
        // 1 nm a step: 100 steps/s² is 0.0001 mm/s², 0.000 as the MMC is written to.
        let too_slow = [
            DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -10.0, acceleration: 100.0 },
            DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: 5000.0, acceleration: 100.0 },
            DriverCommand::Move {
                position: 1000.0,
                relative: false,
                min_velocity: 0.0,
                max_velocity: 400.0,
                acceleration: 2e5,
            },
            DriverCommand::Home { forward: true, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 400.0 },
        ];
        for command in too_slow {
            let mut lb = MICRONIX.up();
            let from = lb.written().len();
            lb.command(0, &command);
            lb.run_for(Duration::from_millis(300));
            let errors = common::controller_errors(&lb.take_events());
            assert!(
                errors.iter().any(|(_, _, m)| m.contains("below the least the MMC takes")),
                "{command:?}: {errors:?}"
            );
            let sent = written_since(&lb, from);
            assert!(sent.iter().all(|l| l.ends_with("?\r")), "only queries: {command:?}: {sent:?}");
            assert_eq!(lb.link.malformed(), 0);
        }
    }

    #[test]
    fn replies_split_at_every_byte_give_the_same_statuses() {
        // The common script's position set of -77 is refused here (ZRO sets 0 only): the
        // statuses are compared as they are.
        let whole = super::statuses_whole_and_in_pieces(&MICRONIX);
        assert!(whole[1].last().is_some_and(|s| s.msta & msta::DONE != 0 && s.position > 0.0), "{:?}", whole[1].last());
    }

    #[test]
    fn a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing() {
        let reads = |l: &str| ["POS?", "STA?", "MOT?", "HOM?"].iter().any(|q| l.ends_with(&format!("{q}\r")));
        super::a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing(
            &MICRONIX,
            |l| l.contains("MVA"),
            reads,
        );
    }
}

mod picomotor {
    use super::*;

    /// A move at the 8742's top speed, 2,000 steps/s.
    fn go(position: f64, relative: bool) -> DriverCommand {
        DriverCommand::Move { position, relative, min_velocity: 0.0, max_velocity: 2000.0, acceleration: 100_000.0 }
    }

    #[test]
    fn a_move_sets_speeds_then_moves_as_motor_new_focus_does_checks_the_error_queue_and_arrives() {
        let mut lb = PICOMOTOR.up();
        no_failed_exchange(&lb.take_events());
        let from = lb.written().len();
        lb.command(1, &go(3000.0, false));
        let arrived = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(5)).last().expect("done");
        assert_eq!(arrived.position, 3000.0);
        let sent = written_since(&lb, from);
        assert_eq!(sent[0], "2 AC 100000\r2 VA 2000\r2 PA 3000\rTB?\r", "{sent:?}");
        lb.command(1, &go(-500.0, true));
        let back = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(5)).last().expect("done");
        assert_eq!(back.position, 2500.0);
    }

    #[test]
    fn a_speed_beyond_the_controller_is_refused_unsent_and_a_refusal_of_its_own_is_in_its_words() {
        let mut lb = PICOMOTOR.up();
        a_speed_is_refused_unsent(&mut lb, 0, 5000.0, &["outside the 8742's 1 to 2000"], " PA ");
        // A position set while moving: the controller's own refusal, read from its error queue.
        lb.command(0, &go(3000.0, false));
        lb.run_for(Duration::from_millis(300));
        lb.command(0, &DriverCommand::SetPosition { position: 5.0 });
        lb.run_for(Duration::from_millis(300));
        let errors = common::controller_errors(&lb.take_events());
        assert!(errors.iter().any(|(_, _, m)| m.contains("MOTION IN PROGRESS")), "{errors:?}");
    }

    #[test]
    fn a_jog_runs_until_stopped() {
        super::a_jog_runs_until_stopped(&PICOMOTOR, 0, -2000.0);
    }

    #[test]
    fn a_home_is_refused_and_a_position_set_is_dh() {
        let mut lb = PICOMOTOR.up();
        let from = lb.written().len();
        let home = DriverCommand::Home { forward: true, min_velocity: 0.0, max_velocity: 2000.0, acceleration: 1e5 };
        lb.command(0, &home);
        lb.run_for(Duration::from_millis(300));
        let errors = common::controller_errors(&lb.take_events());
        assert!(errors.iter().any(|(_, _, m)| m.contains("no home switch")), "{errors:?}");
        lb.command(0, &DriverCommand::SetPosition { position: 250.0 });
        lb.run_for(Duration::from_millis(1500));
        assert_eq!(common::last_status(&lb.take_events(), 0).position, 250.0);
        assert!(written_since(&lb, from).iter().any(|l| l.starts_with("1 DH 250\r")));
    }

    #[test]
    fn replies_split_at_every_byte_give_the_same_statuses() {
        // The common script's speeds are above the 8742's (refused): the statuses are compared
        // as they are.
        let whole = super::statuses_whole_and_in_pieces(&PICOMOTOR);
        assert!(!whole[0].is_empty() && !whole[1].is_empty());
    }

    #[test]
    fn a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing() {
        let reads = |l: &str| l.ends_with("TP?\r") || l.ends_with("MD?\r");
        super::a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing(
            &PICOMOTOR,
            |l| l.contains(" PA "),
            reads,
        );
    }
}

mod piezojena {
    use super::*;

    #[test]
    fn a_move_takes_serial_control_closes_the_loop_sets_the_target_and_arrives() {
        let mut lb = PIEZO.up();
        no_failed_exchange(&lb.take_events());
        let from = lb.written().len();
        lb.command(1, &go(12_345.0, false));
        let arrived = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(2)).last().expect("done");
        assert_eq!((arrived.position, arrived.msta & msta::PROBLEM), (12_345.0, 0), "{arrived:?}");
        let sent = written_since(&lb, from);
        assert_eq!(sent[..3], ["setk,1,1\r", "cloop,1,1\r", "set,1,12.345\r"], "{sent:?}");
        lb.command(1, &go(-2_345.0, true));
        let back = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(2)).last().expect("done");
        assert_eq!(back.position, 10_000.0, "{back:?}");
    }

    #[test]
    fn a_target_beyond_the_stroke_is_refused_unsent() {
        let mut lb = PIEZO.up();
        let from = lb.written().len();
        lb.command(0, &go(150_000.0, false));
        lb.run_for(Duration::from_millis(300));
        let errors = common::controller_errors(&lb.take_events());
        assert!(
            errors.iter().any(|(c, _, m)| *c == Some(0) && m.contains("outside the stage's 0 to 100 um")),
            "{errors:?}"
        );
        assert!(!written_since(&lb, from).iter().any(|l| l.starts_with("set,")), "nothing sent");
    }

    #[test]
    fn a_jog_goes_to_the_end_of_the_stroke_and_a_home_is_refused() {
        let mut lb = PIEZO.up();
        let jog = DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: 1000.0, acceleration: 1e4 };
        lb.command(0, &jog);
        let end = *run_until_done(&mut lb, 0, TICK, Duration::from_secs(2)).last().expect("done");
        assert_eq!(end.position, 100_000.0, "{end:?}");
        let home = DriverCommand::Home { forward: true, min_velocity: 0.0, max_velocity: 1000.0, acceleration: 1e4 };
        lb.command(0, &home);
        lb.run_for(Duration::from_millis(300));
        let errors = common::controller_errors(&lb.take_events());
        assert!(errors.iter().any(|(_, _, m)| m.contains("no home")), "{errors:?}");
    }

    #[test]
    fn replies_split_at_every_byte_give_the_same_statuses() {
        let whole = super::statuses_whole_and_in_pieces(&PIEZO);
        assert!(whole[0].iter().any(|s| s.position == 3000.0), "{:?}", whole[0]);
    }

    #[test]
    fn a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing() {
        let reads = |l: &str| l.starts_with("rk,") || l.starts_with("stat,") || l == "ERROR\r";
        super::a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing(
            &PIEZO,
            |l| l.starts_with("set,"),
            reads,
        );
    }
}

mod faulhaber {
    use super::*;

    #[test]
    fn a_move_is_confirmed_sets_speeds_in_rpm_loads_and_starts_as_motor_faulhaber_does_and_arrives() {
        let mut lb = FAULHABER.up();
        no_failed_exchange(&lb.take_events());
        let from = lb.written().len();
        common::a_move_arrives_where_asked_and_a_relative_one_from_there(&mut lb, 2, go);
        let sent = written_since(&lb, from);
        // The resolution is read once, by the first poll, and kept.
        let everything = written_since(&lb, 0);
        assert_eq!(everything.iter().filter(|l| *l == "2GENCRES\r").count(), 1, "{everything:?}");
        assert!(everything[..from].contains(&"2GENCRES\r".to_string()), "{everything:?}");
        // 20,000 steps/s at 4,096 increments a revolution: 293 rpm; 200,000 steps/s²: 49 /s².
        let first = ["2ANSW2\r", "2SP293\r", "2AC49\r", "2DEC49\r", "2LA12345\r", "2M\r"];
        assert_eq!(sent[..6], first, "{sent:?}");
        let relative = ["2POS\r", "2ANSW2\r", "2SP293\r", "2AC49\r", "2DEC49\r", "2LA10000\r", "2M\r"];
        assert!(sent.windows(7).any(|w| w == relative), "a relative move is from where the drive is: {sent:?}");
    }

    #[test]
    fn a_jog_runs_until_stopped_and_the_stop_is_v0() {
        super::a_jog_runs_until_stopped(&FAULHABER, 1, -5000.0);
        let mut lb = FAULHABER.up();
        let from = lb.written().len();
        lb.command(1, &DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -5000.0, acceleration: 5e4 });
        lb.run_for(Duration::from_millis(300));
        stop(&mut lb, 1);
        let sent = written_since(&lb, from);
        assert!(sent.windows(3).any(|w| w == ["1SP73\r", "1AC12\r", "1V-73\r"]), "{sent:?}");
        assert!(sent.contains(&"1V0\r".to_string()), "{sent:?}");
    }

    #[test]
    fn a_homing_sequence_ends_at_zero_on_the_home_switch_and_the_axis_is_homed() {
        let mut lb = FAULHABER.up();
        lb.command(1, &go(30_000.0, false));
        run_until_done(&mut lb, 1, TICK, Duration::from_secs(5));
        let from = lb.written().len();
        let home = DriverCommand::Home { forward: false, min_velocity: 0.0, max_velocity: 20_000.0, acceleration: 2e5 };
        lb.command(1, &home);
        let homed = *run_until_done(&mut lb, 1, TICK, Duration::from_secs(20)).last().expect("done");
        assert_eq!(homed.position, 0.0, "{homed:?}");
        assert_eq!(homed.msta & (msta::HOMED | msta::HOME | msta::PROBLEM), msta::HOMED | msta::HOME, "{homed:?}");
        let sent = written_since(&lb, from);
        assert!(sent.windows(2).any(|w| w == ["1HOSP-293\r", "1GOHOSEQ\r"]), "{sent:?}");
    }

    #[test]
    fn a_speed_under_one_rpm_is_refused_unsent() {
        let mut lb = FAULHABER.up();
        a_speed_is_refused_unsent(&mut lb, 1, 20.0, &["faulhaber_mc.lua:", "under 1 rpm"], "SP");
    }

    #[test]
    fn the_drives_refusals_are_in_its_words_and_an_overtemperature_is_a_problem() {
        let mut lb = FAULHABER.up();
        lb.command(1, &DriverCommand::Enable { on: false });
        lb.command(1, &go(5000.0, false));
        lb.run_for(Duration::from_millis(500));
        let errors = common::controller_errors(&lb.take_events());
        assert!(errors.iter().any(|(_, _, m)| m.contains("1M: Command not available")), "{errors:?}");
        assert!(!lb.link.emulator().axis(1).expect("node 1").is_moving());
        lb.command(1, &DriverCommand::Enable { on: true });
        lb.run_for(Duration::from_millis(300));
        assert!(lb.link.emulator().raise_error(2));
        lb.run_for(Duration::from_millis(1500));
        let status = common::last_status(&lb.take_events(), 2);
        assert_ne!(status.msta & msta::PROBLEM, 0, "{status:?}");
        lb.command(2, &go(5000.0, false));
        lb.run_for(Duration::from_millis(500));
        let errors = common::controller_errors(&lb.take_events());
        assert!(errors.iter().any(|(_, _, m)| m.contains("Overtemperature - drive disabled")), "{errors:?}");
    }

    #[test]
    fn node_zero_every_drive_at_once_is_refused() {
        let everyone = Family { channels: [0, 1], ..FAULHABER };
        let mut lb = everyone.loopback(Faults::default());
        lb.run_for(Duration::from_millis(300));
        let errors = common::controller_errors(&lb.take_events());
        assert!(errors.iter().any(|(c, _, m)| *c == Some(0) && m.contains("not a node number")), "{errors:?}");
        assert!(lb.written().iter().all(|l| !l.starts_with(b"0") && l.first().is_some_and(u8::is_ascii_digit)));
    }

    #[test]
    fn replies_split_at_every_byte_give_the_same_statuses() {
        common::replies_in_pieces_give_the_same_statuses_on(
            |chunk| FAULHABER.loopback(Faults::default()).with_chunks(chunk),
            &FAULHABER.channels,
        );
    }

    #[test]
    fn a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing() {
        let reads = |l: &str| ["POS", "OST", "GN"].iter().any(|q| l.len() > 1 && l[1..] == format!("{q}\r"));
        super::a_lost_reply_sends_no_move_twice_and_a_new_connection_moves_nothing(
            &FAULHABER,
            |l| l.contains("LA"),
            reads,
        );
    }
}
