//! Every protocol and every family zmotor scripts, against its emulator in virtual time on a
//! slow link: the status that first says a motion is over has the position the motor rests at,
//! so DMOV 1 comes with the final readback. A poll reads a controller's state and its position
//! in separate requests; read position first (as several EPICS drivers do), a motion that ends
//! between the two leaves its last steps to the next poll, after DMOV 1.

mod common;

use common::{bring_up, done_comes_with_the_final_position, go, home_and_wait, loopback, script_loopback, switched_on};
use std::time::Duration;
use zmotor_controllers::{Loopback, ProtocolKind};
use zmotor_emulators::{Faults, Model, WithFaults};
use zmotor_msgs::DriverCommand;

/// Each reply this late: a poll's readings are milliseconds apart, as on a busy or serial line.
fn slow(lb: &mut Loopback) {
    lb.link.set_faults(Faults { delay: Duration::from_millis(3), ..Faults::default() });
}

/// `kind` up on `channels`, `channel` checked.
fn protocol(kind: ProtocolKind, channels: &[usize], channel: usize) {
    let mut lb = loopback(kind, channels, Faults::default());
    bring_up(&mut lb);
    slow(&mut lb);
    done_comes_with_the_final_position(&mut lb, channel, go);
}

/// `kind` up on `channels`, every channel switched on first, `channel` checked.
fn protocol_switched_on(kind: ProtocolKind, channels: &[usize], channel: usize) {
    let mut lb = switched_on(kind, channels);
    slow(&mut lb);
    done_comes_with_the_final_position(&mut lb, channel, go);
}

/// The family scripted in `script` driving `model` on channels 0 and 1 (or `channels`).
fn family(script: &str, model: Model, channels: [usize; 2]) {
    let source = common::script_source(script, "ctl", &[]);
    let mut lb = script_loopback(&source, model, &channels, Faults::default());
    bring_up(&mut lb);
    slow(&mut lb);
    done_comes_with_the_final_position(&mut lb, channels[1], go);
}

#[test]
fn acs_mcb4b() {
    protocol(ProtocolKind::AcsMcb4b, &[1], 1);
}

#[test]
fn ims_mdrive_on_its_9600_baud_line() {
    let mut lb = loopback(ProtocolKind::ImsMdrive, &[1, 2], Faults::default());
    lb.link = WithFaults::new(common::emulator(ProtocolKind::ImsMdrive, 3), Faults::default()).at_baud(9600);
    lb.run_for(Duration::from_secs(2));
    bring_up(&mut lb);
    done_comes_with_the_final_position(&mut lb, 2, go);
}

#[test]
fn mclennan_pm304() {
    protocol(ProtocolKind::McLennanPm304, &[1, 2], 2);
}

#[test]
fn oms_maxnet() {
    protocol(ProtocolKind::OmsMaxnet, &[0, 2], 2);
}

#[test]
fn phytron() {
    protocol(ProtocolKind::Phytron, &[11, 12], 12);
}

#[test]
fn pmac() {
    protocol(ProtocolKind::Pmac, &[1, 2], 1);
}

#[test]
fn smaract_mcs2() {
    protocol(ProtocolKind::SmaractMcs2, &[1], 1);
}

#[test]
fn galil() {
    protocol_switched_on(ProtocolKind::Galil, &[0, 1], 1);
}

#[test]
fn newport_esp300() {
    protocol_switched_on(ProtocolKind::NewportEsp300, &[1, 2], 2);
}

#[test]
fn newport_smc100_homed() {
    let mut lb = loopback(ProtocolKind::NewportSmc100, &[1], Faults::default());
    bring_up(&mut lb);
    home_and_wait(&mut lb, 1);
    slow(&mut lb);
    done_comes_with_the_final_position(&mut lb, 1, go);
}

#[test]
fn newport_xps_homed() {
    let mut lb = loopback(ProtocolKind::NewportXps, &[1, 2], Faults::default());
    bring_up(&mut lb);
    for channel in [1, 2] {
        home_and_wait(&mut lb, channel);
    }
    slow(&mut lb);
    done_comes_with_the_final_position(&mut lb, 2, go);
}

#[test]
fn pi_gcs2_referenced() {
    let mut lb = loopback(ProtocolKind::PiGcs2, &[1], Faults::default());
    bring_up(&mut lb);
    // A position set makes the axis count as referenced, so that it may move.
    lb.command(1, &DriverCommand::SetPosition { position: 0.0 });
    lb.run_for(Duration::from_millis(100));
    slow(&mut lb);
    done_comes_with_the_final_position(&mut lb, 1, go);
}

#[test]
fn faulhaber_script() {
    family("launch/scripts/faulhaber_mc.lua", Model::FaulhaberMc, [1, 2]);
}

#[test]
fn kohzu_script() {
    family("launch/scripts/kohzu_sc.lua", Model::KohzuSc, [0, 1]);
}

#[test]
fn micronix_script() {
    family("launch/scripts/micronix_mmc.lua", Model::MicronixMmc, [0, 1]);
}

#[test]
fn newfocus_picomotor_script() {
    family("launch/scripts/newfocus_8742.lua", Model::NewFocus8742, [0, 1]);
}

#[test]
fn piezojena_script() {
    family("launch/scripts/piezojena_nv40.lua", Model::PiezojenaNv40, [0, 1]);
}
