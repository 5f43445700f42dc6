//! Soft Channel device support and the input/output links, through the sans-IO axis
//! (spec §16 and worked scenarios W58 and W62).

use zmotor_core::{Axis, AxisEvent, InputLink, Instant, PollRates, SimAxis, SimConfig, SOFT_DONE_SETTLE};
use zmotor_msgs::{Field, Fields, Value};

fn at(seconds: f64) -> Instant {
    Instant::from_secs_f64(seconds)
}

/// W62's soft motor: OUT to a calc input, readback from RDBL, done from the driven motor.
fn soft_fields() -> Fields {
    Fields {
        dtyp: "Soft Channel".into(),
        out: "calc/drive/A".into(),
        rdbl: "calc/readback".into(),
        urip: 1,
        rres: 1.0,
        mres: 0.001,
        dinp: "motor/lin/DMOV".into(),
        stoo: "motor/lin/STOP".into(),
        rtry: 0,
        ntm: 0,
        ..Fields::default()
    }
}

fn puts(events: &[AxisEvent]) -> Vec<(String, String)> {
    events
        .iter()
        .filter_map(|e| if let AxisEvent::Put { key, value } = e { Some((key.clone(), value.clone())) } else { None })
        .collect()
}

fn posts(events: &[AxisEvent], field: Field) -> Vec<Value> {
    events
        .iter()
        .filter_map(|e| if let AxisEvent::Post(f, v) = e { (*f == field).then(|| v.clone()) } else { None })
        .collect()
}

fn drain(axis: &mut Axis) -> Vec<AxisEvent> {
    axis.drain_events().collect()
}

fn booted_soft() -> Axis {
    let mut axis = Axis::new_soft(soft_fields(), PollRates::default(), Instant::ZERO);
    drain(&mut axis);
    // (a) the first readback resets the target to it, once.
    axis.link_update(at(0.0), InputLink::Readback, 0.5);
    let events = drain(&mut axis);
    assert_eq!(posts(&events, Field::DMOV), vec![Value::Int(0), Value::Int(1)]);
    assert_eq!(posts(&events, Field::PP), vec![Value::Int(1)]);
    let f = axis.fields();
    assert_eq!((f.rmp, f.rrbv, f.drbv, f.val, f.dval, f.dmov), (500, 500, 0.5, 0.5, 0.5, 1));
    axis
}

#[test]
fn w62a_the_first_readback_sets_the_target() {
    booted_soft();
}

#[test]
fn w62b_a_move_writes_dval_to_out_and_completes_with_dinp() {
    let mut axis = booted_soft();
    axis.write(at(1.0), Field::VAL, &Value::Float(1.0)).unwrap();
    let events = drain(&mut axis);
    assert_eq!(puts(&events), vec![("calc/drive/A".to_string(), "1".to_string())]);
    assert_eq!(posts(&events, Field::DMOV), vec![Value::Int(0)]);
    axis.link_update(at(1.1), InputLink::Done, 0.0);
    axis.link_update(at(1.2), InputLink::Readback, 0.7);
    assert_eq!((axis.fields().movn, axis.fields().rrbv, axis.fields().dmov), (1, 700, 0));
    axis.link_update(at(1.4), InputLink::Done, 1.0);
    // "Done" waits a moment for the readback, which comes one link later.
    axis.link_update(at(1.41), InputLink::Readback, 1.0);
    assert_eq!(axis.fields().dmov, 0);
    axis.handle_timeout(at(1.4) + SOFT_DONE_SETTLE);
    let f = axis.fields();
    assert_eq!((f.movn, f.dmov, f.rbv, f.val), (0, 1, 1.0, 1.0));
}

#[test]
fn w62c_an_external_move_of_the_driven_motor_resynchronises_unless_locked() {
    let mut axis = booted_soft();
    axis.link_update(at(1.0), InputLink::Done, 0.0);
    let events = drain(&mut axis);
    assert_eq!(posts(&events, Field::DMOV), vec![Value::Int(0)]);
    assert_eq!(posts(&events, Field::PP), vec![Value::Int(1)]);
    axis.link_update(at(1.1), InputLink::Readback, 0.8);
    axis.link_update(at(1.2), InputLink::Done, 1.0);
    axis.handle_timeout(at(1.2) + SOFT_DONE_SETTLE);
    let f = axis.fields();
    assert_eq!((f.val, f.dval, f.dmov), (0.8, 0.8, 1));

    let mut axis = Axis::new_soft(Fields { lock: 1, ..soft_fields() }, PollRates::default(), Instant::ZERO);
    axis.link_update(at(0.0), InputLink::Readback, 0.5);
    drain(&mut axis);
    axis.link_update(at(1.0), InputLink::Done, 0.0);
    assert!(posts(&drain(&mut axis), Field::DMOV).is_empty());
    axis.link_update(at(1.1), InputLink::Readback, 0.8);
    axis.link_update(at(1.2), InputLink::Done, 1.0);
    axis.handle_timeout(at(1.2) + SOFT_DONE_SETTLE);
    let f = axis.fields();
    assert_eq!((f.val, f.rbv, f.dmov), (0.5, 0.8, 1), "readback follows, the target does not");
}

#[test]
fn w62d_stop_writes_stoo() {
    let mut axis = booted_soft();
    axis.write(at(1.0), Field::VAL, &Value::Float(2.0)).unwrap();
    axis.link_update(at(1.1), InputLink::Done, 0.0);
    drain(&mut axis);
    axis.write(at(1.2), Field::STOP, &Value::Int(1)).unwrap();
    assert_eq!(puts(&drain(&mut axis)), vec![("motor/lin/STOP".to_string(), "1".to_string())]);
}

#[test]
fn w62e_backlash_legs_all_write_the_final_target() {
    let mut axis = Axis::new_soft(Fields { bdst: 0.5, ..soft_fields() }, PollRates::default(), Instant::ZERO);
    axis.link_update(at(0.0), InputLink::Readback, 0.0);
    drain(&mut axis);
    axis.write(at(1.0), Field::VAL, &Value::Float(2.0)).unwrap();
    assert_eq!(puts(&drain(&mut axis)), vec![("calc/drive/A".to_string(), "2".to_string())]);
    // Without DINP motion the first readback completes the first leg; the backlash leg follows.
    axis.link_update(at(1.1), InputLink::Readback, 1.5);
    assert_eq!(puts(&drain(&mut axis)), vec![("calc/drive/A".to_string(), "2".to_string())]);
}

#[test]
fn soft_channel_has_no_status_refresh() {
    let mut axis = booted_soft();
    axis.write(at(1.0), Field::STUP, &Value::Int(1)).unwrap();
    assert_eq!(axis.fields().stup, 0, "GET_INFO is refused, STUP snaps back to OFF");
}

fn sim_axis(fields: Fields) -> Axis {
    Axis::new(fields, Box::new(SimAxis::new(SimConfig::default())), PollRates::default(), Instant::ZERO)
}

#[test]
fn w58_urip_reads_the_readback_link() {
    let fields =
        Fields { mres: 0.01, velo: 1.0, urip: 1, rres: 1.0, rtry: 0, rdbl: "lab/encoder".into(), ..Fields::default() };
    let mut axis = sim_axis(fields.clone());
    // Not readable yet: a move is refused, nothing sent.
    let err = axis.write(at(0.0), Field::VAL, &Value::Float(1.0)).unwrap_err();
    assert_eq!(err.to_string(), "VAL: the readback link RDBL (lab/encoder) cannot be read");
    assert_eq!((axis.fields().val, axis.fields().dmov, axis.fields().lvio), (0.0, 1, 0));
    axis.link_update(at(0.1), InputLink::Readback, 0.123);
    axis.refresh_status(at(0.1));
    let f = axis.fields();
    assert_eq!((f.rrbv, f.drbv, f.rbv), (12, 0.12, 0.12));
}

#[test]
fn rlnk_and_flnk_write_their_keys() {
    let fields =
        Fields { mres: 0.01, velo: 100.0, rlnk: "lab/rbv".into(), flnk: "lab/next/PROC".into(), ..Fields::default() };
    let mut axis = sim_axis(fields);
    drain(&mut axis);
    axis.write(at(0.0), Field::VAL, &Value::Float(1.0)).unwrap();
    let mut all = drain(&mut axis);
    for _ in 0..100 {
        let t = axis.poll_timeout().expect("a simulated axis is polled");
        axis.handle_timeout(t);
        all.extend(drain(&mut axis));
        if !axis.is_busy() {
            break;
        }
    }
    let written = puts(&all);
    assert!(written.iter().any(|(k, _)| k == "lab/rbv"), "{written:?}");
    assert_eq!(written.last(), Some(&("lab/next/PROC".to_string(), "1".to_string())));
    assert_eq!(written.iter().filter(|(k, _)| k == "lab/next/PROC").count(), 1, "none while it moved");
    // As the record's forward link (spec Q35): at every processing that ends with DMOV 1, here a
    // put that moves nothing and a put of a field that processes the record.
    axis.write(at(10.0), Field::VAL, &Value::Float(1.0)).unwrap();
    let flnk = |events: &[AxisEvent]| puts(events).iter().filter(|(k, _)| k == "lab/next/PROC").count();
    assert_eq!(flnk(&drain(&mut axis)), 1, "a put that moves nothing");
    axis.write(at(11.0), Field::HLM, &Value::Float(50.0)).unwrap();
    // Processed by the put, then by the status the limit's command asks for: each fires it.
    assert_eq!(flnk(&drain(&mut axis)), 2, "a put of a field that processes the record, no motion");
    let t = axis.poll_timeout().expect("polled at rest");
    axis.handle_timeout(t);
    assert_eq!(flnk(&drain(&mut axis)), 0, "a poll at rest that changes nothing processes nothing");
}

#[test]
fn dol_drives_the_target_in_closed_loop() {
    let fields = Fields { mres: 0.01, velo: 100.0, omsl: 1, dol: "lab/setpoint".into(), ..Fields::default() };
    let mut axis = sim_axis(fields);
    // Undefined until the link is first read (§6.2 step 6: UDF is cleared at boot only for a
    // constant DOL): the UDF alarm, INVALID.
    assert_eq!((axis.fields().udf, axis.fields().sevr), (1, 3));
    axis.link_update(at(0.0), InputLink::Desired, 0.5);
    assert_eq!(axis.fields().udf, 0, "a good read defines it");
    assert_eq!((axis.fields().val, axis.fields().dval, axis.fields().dmov), (0.5, 0.5, 0));
    for _ in 0..100 {
        let t = axis.poll_timeout().expect("a simulated axis is polled");
        axis.handle_timeout(t);
        if !axis.is_busy() {
            break;
        }
    }
    assert_eq!(axis.fields().rbv, 0.5);
}

#[test]
fn a_dol_read_when_its_link_connects_moves_nothing_and_its_next_update_drives() {
    let fields = Fields { mres: 0.01, velo: 100.0, omsl: 1, dol: "lab/setpoint".into(), ..Fields::default() };
    let mut axis = sim_axis(fields);
    // At connect, or when the source comes back: no motion from a (re)connection.
    axis.link_read(at(0.0), InputLink::Desired, 0.5);
    let f = axis.fields();
    assert_eq!((f.val, f.dmov, f.udf), (0.0, 1, 1), "nothing moved, still undefined");
    axis.link_update(at(1.0), InputLink::Desired, 0.7);
    assert_eq!((axis.fields().val, axis.fields().dmov, axis.fields().udf), (0.7, 0, 0));
    // Other links are read at connect as updates.
    let mut soft = booted_soft();
    soft.link_read(at(1.0), InputLink::Readback, 0.25);
    assert_eq!(soft.fields().rbv, 0.25);
}

#[test]
fn a_move_commanded_while_the_driven_motor_settles_waits_for_its_own_motion() {
    let mut axis = booted_soft();
    // The driven motor moved on its own and has just reported done; that "done" is settling.
    axis.link_update(at(1.0), InputLink::Done, 0.0);
    axis.link_update(at(1.1), InputLink::Readback, 0.8);
    axis.link_update(at(1.2), InputLink::Done, 1.0);
    assert_eq!(posts(&drain(&mut axis), Field::DMOV), vec![Value::Int(0)]);
    // A move commanded now comes after that completion (the reference processes the DINP
    // callback before a later put): the old "done" must not end the new move.
    axis.write(at(1.21), Field::VAL, &Value::Float(2.0)).unwrap();
    let events = drain(&mut axis);
    assert_eq!(puts(&events), vec![("calc/drive/A".to_string(), "2".to_string())]);
    assert_eq!(posts(&events, Field::DMOV), vec![Value::Int(1), Value::Int(0)]);
    axis.handle_timeout(at(1.2) + SOFT_DONE_SETTLE);
    assert_eq!(axis.fields().dmov, 0, "the new move is still waiting for the driven motor");
    axis.link_update(at(1.3), InputLink::Done, 0.0);
    axis.link_update(at(1.5), InputLink::Readback, 2.0);
    axis.link_update(at(1.6), InputLink::Done, 1.0);
    axis.handle_timeout(at(1.6) + SOFT_DONE_SETTLE);
    let f = axis.fields();
    assert_eq!((f.dmov, f.rbv, f.val), (1, 2.0, 2.0));
}

#[test]
fn a_readback_link_whose_source_is_gone_stops_the_motion_and_moves_nothing_until_it_is_back() {
    // Spec §5.10: RDBL unreadable freezes the readback, stops a motion under way (STOP, as
    // STOO writes it) and refuses new moves; the source's node stopping makes it unreadable.
    let mut axis = booted_soft();
    axis.write(at(1.0), Field::VAL, &Value::Float(1.0)).unwrap();
    axis.link_update(at(1.1), InputLink::Done, 0.0);
    axis.link_update(at(1.2), InputLink::Readback, 0.7);
    drain(&mut axis);
    axis.link_lost(at(1.3), InputLink::Readback);
    let events = drain(&mut axis);
    assert!(puts(&events).contains(&("motor/lin/STOP".to_string(), "1".to_string())), "{events:?}");
    assert!((axis.fields().drbv - 0.7).abs() < 1e-9, "the readback frozen: {}", axis.fields().drbv);
    axis.link_update(at(1.4), InputLink::Done, 1.0);
    axis.handle_timeout(at(1.4) + SOFT_DONE_SETTLE);
    drain(&mut axis);
    // While it cannot be read, a new target drives nothing.
    let _ = axis.write(at(2.0), Field::VAL, &Value::Float(2.0));
    let events = drain(&mut axis);
    assert!(!puts(&events).iter().any(|(key, _)| key == "calc/drive/A"), "no move on a lost readback: {events:?}");
    // Read again, moves go.
    axis.link_update(at(3.0), InputLink::Readback, 0.7);
    drain(&mut axis);
    axis.write(at(3.1), Field::VAL, &Value::Float(1.5)).unwrap();
    let events = drain(&mut axis);
    assert!(puts(&events).iter().any(|(key, _)| key == "calc/drive/A"), "{events:?}");
}
