//! Channel Access for zmotor axes, sans-IO. A CA client (caget, pyepics, ophyd, CS-Studio) sees
//! each live axis as a motor record: `<P><axis>` its VAL, `<P><axis>.<FIELD>` every field of the
//! catalogue, `.RTYP` `motor`. The subset of the protocol served: name search (UDP), version,
//! create and clear channel, read, write, write with notification (put-callback), subscribe and
//! unsubscribe, echo, flow control, server disconnect. The gateway (zmotor-ca) moves the bytes
//! and holds the values. The message codec is public: a client (the benchmark's) speaks it too.

mod circuit;
pub mod codec;
mod dbr;
mod directory;
mod names;
mod search;

pub use circuit::{Circuit, Request, WriteAnswer, WriteEnd};
pub use dbr::{Base, Snapshot, Stamp};
pub use directory::Directory;
pub use names::{Limits, Pv, Target, ABLE, MESSAGE_CHARS};
pub use search::answer as answer_search;

#[cfg(test)]
mod tests {
    use super::codec::{self, command, Header, MINOR_VERSION};
    use super::*;
    use zmotor_msgs::{BridgeRecord, Field, Value};

    /// One live axis, m1, whose VAL is 2.5 once fetched; and two bridge records, the value
    /// holder `arm` and the calc `angle`.
    struct OneAxis {
        fetched: bool,
    }

    impl Directory for OneAxis {
        fn is_live(&self, axis: &str) -> bool {
            axis == "m1"
        }

        fn bridge_record(&self, name: &str) -> Option<BridgeRecord> {
            match name {
                "arm" | "gate_able" => Some(BridgeRecord::Value),
                "angle" => Some(BridgeRecord::Calc),
                _ => None,
            }
        }

        fn snapshot(&self, pv: &Pv) -> Option<Snapshot> {
            self.fetched.then(|| Snapshot {
                value: Value::Float(2.5),
                native: pv.native(),
                status: 0,
                severity: 0,
                acknowledgement: (1, 0),
                stamp: Stamp::default(),
                units: "mm".into(),
                precision: 2,
                upper: 10.0,
                lower: -10.0,
                alarm: [f64::NAN; 4],
                choices: &[],
            })
        }
    }

    /// Every message of some bytes.
    fn messages(bytes: &[u8]) -> Vec<(Header, Vec<u8>)> {
        let mut out = Vec::new();
        let mut rest = bytes;
        while let Ok(Some((header, payload, used))) = codec::parse(rest) {
            out.push((header, payload.to_vec()));
            rest = &rest[used..];
        }
        out
    }

    fn request(
        circuit: &mut Circuit,
        directory: &dyn Directory,
        header: Header,
        payload: &[u8],
    ) -> Vec<(Header, Vec<u8>)> {
        circuit.handle_input(&codec::encode(header, payload), directory).unwrap();
        messages(&circuit.poll_transmit().unwrap_or_default())
    }

    #[test]
    fn a_channel_is_created_read_once_its_axis_is_fetched_and_monitored() {
        let mut circuit = Circuit::new("");
        let mut directory = OneAxis { fetched: false };
        let version = request(&mut circuit, &directory, Header::new(command::VERSION, 0, 13, 0, 0), &[]);
        assert_eq!(version[0].0.count, u32::from(MINOR_VERSION));
        let created = request(&mut circuit, &directory, Header::new(command::CREATE_CHAN, 0, 0, 7, 13), b"m1\0");
        assert_eq!((created[0].0.command, created[0].0.p2), (command::ACCESS_RIGHTS, 3));
        let (reply, _) = &created[1];
        assert_eq!((reply.command, reply.data_type, reply.p1), (command::CREATE_CHAN, 6, 7));
        let sid = reply.p2;
        assert_eq!(circuit.poll_request(), Some(Request::Fetch { axis: "m1".into() }));

        // A read and a subscription before the values arrive wait for them.
        assert!(request(&mut circuit, &directory, Header::new(command::READ_NOTIFY, 6, 1, sid, 99), &[]).is_empty());
        let plain = request(&mut circuit, &directory, Header::new(command::EVENT_ADD, 6, 1, sid, 4), &[0; 16]);
        assert!(plain.is_empty());
        directory.fetched = true;
        circuit.values_arrived("m1", &directory);
        let read = messages(&circuit.poll_transmit().unwrap());
        assert_eq!((read[0].0.command, read[0].0.p1, read[0].0.p2), (command::READ_NOTIFY, 1, 99));
        assert_eq!(read[0].1, 2.5f64.to_be_bytes());
        assert_eq!((read[1].0.command, read[1].0.p2), (command::EVENT_ADD, 4));
        circuit.values_arrived("m1", &directory);
        assert_eq!(circuit.poll_transmit(), None, "posted once");

        // A CTRL subscription gets the value at once and again when the limits change.
        let mut add = vec![0; 16];
        add[12..14].copy_from_slice(&5u16.to_be_bytes());
        let first = request(&mut circuit, &directory, Header::new(command::EVENT_ADD, 34, 1, sid, 5), &add);
        assert_eq!((first[0].0.command, first[0].0.p2, first[0].1.len()), (command::EVENT_ADD, 5, 88));
        circuit.handle_change("m1", Target::Field(Field::HLM), &directory);
        assert_eq!(messages(&circuit.poll_transmit().unwrap()).len(), 1);
        circuit.handle_change("m1", Target::Field(Field::VELO), &directory);
        assert_eq!(circuit.poll_transmit(), None, "VELO is not VAL's metadata");

        // The axis goes: the client hears its channel is disconnected.
        circuit.axis_gone("m1");
        let gone = messages(&circuit.poll_transmit().unwrap());
        assert_eq!((gone[0].0.command, gone[0].0.p1), (command::SERVER_DISCONN, 7));
    }

    #[test]
    fn a_bridge_record_is_found_read_and_written_as_an_ao_or_read_as_a_calc() {
        let mut circuit = Circuit::new("bl:");
        let directory = OneAxis { fetched: true };
        let search = |name: &str| {
            let datagram = codec::encode(Header::new(command::SEARCH, 0, 13, 1, 1), &codec::name_payload(name));
            search::answer("bl:", &datagram, 5064, &directory).is_some()
        };
        assert!(search("bl:arm") && search("bl:arm.VAL") && search("bl:angle.RTYP"));
        assert!(!search("bl:arm.EGU") && !search("bl:nothing") && !search("bl:arm.RBV"), "a value and its type only");
        let mut create = |cid, name: &[u8]| {
            let created = request(&mut circuit, &directory, Header::new(command::CREATE_CHAN, 0, 0, cid, 13), name);
            (created[0].0.p2, created.get(1).map(|(reply, _)| (reply.command, reply.data_type, reply.p2)))
        };
        let (arm_rights, arm) = create(1, b"bl:arm\0");
        let (angle_rights, angle) = create(2, b"bl:angle.VAL\0");
        let (_, angle_type) = create(3, b"bl:angle.RTYP\0");
        assert_eq!((arm_rights, angle_rights), (3, 1), "an ao is written, a calc's result read");
        let [Some((command::CREATE_CHAN, 6, arm)), Some((command::CREATE_CHAN, 6, angle)), Some((_, 0, angle_type))] =
            [arm, angle, angle_type]
        else {
            panic!("channels: {arm:?} {angle:?} {angle_type:?}");
        };
        let read = request(&mut circuit, &directory, Header::new(command::READ_NOTIFY, 0, 1, angle_type, 9), &[]);
        assert_eq!(read[0].1[..5], *b"calc\0");
        let class = request(&mut circuit, &directory, Header::new(command::READ_NOTIFY, 38, 1, arm, 10), &[]);
        assert_eq!(class[0].1[..3], *b"ao\0", "DBR_CLASS_NAME");

        request(&mut circuit, &directory, Header::new(command::WRITE_NOTIFY, 6, 1, arm, 42), &1.5f64.to_be_bytes());
        let Some(Request::Write { pv, text, wait, hold, answer }) = circuit.poll_request() else { panic!("no write") };
        assert_eq!(pv, Pv { axis: "arm".into(), target: Target::BridgeValue(BridgeRecord::Value) });
        assert_eq!((pv.name("bl:"), text.as_str(), wait, hold), ("bl:arm.VAL".into(), "1.5", false, false));
        assert_eq!(pv.written(text), None, "no field of a motor");
        circuit.write_done(answer, WriteEnd::Done, &directory);
        let done = messages(&circuit.poll_transmit().unwrap());
        assert_eq!((done[0].0.command, done[0].0.p1, done[0].0.p2), (command::WRITE_NOTIFY, 1, 42));
        // A calc's result is not written; an acknowledgement has no alarm of a motor to reach.
        let refused = request(&mut circuit, &directory, Header::new(command::WRITE, 6, 1, angle, 3), &[0; 8]);
        assert_eq!((refused[0].0.command, refused[0].0.p2), (command::ERROR, 376), "ECA_NOWTACCESS");
        let acks = request(&mut circuit, &directory, Header::new(command::WRITE_NOTIFY, 36, 1, arm, 4), &[0, 3]);
        assert_eq!((acks[0].0.command, acks[0].0.p1), (command::WRITE_NOTIFY, 1));
        let acks = request(&mut circuit, &directory, Header::new(command::WRITE_NOTIFY, 36, 1, angle, 5), &[0, 3]);
        assert_eq!((acks[0].0.command, acks[0].0.p1), (command::WRITE_NOTIFY, 376), "not on a read-only channel");
        assert_eq!(circuit.poll_request(), None, "nothing sent for any");

        // A live axis of the name is the axis; a record's name may end in `_able`.
        let pv = crate::directory::resolve("", "m1", &directory).unwrap();
        assert_eq!(pv.target, Target::Field(Field::VAL));
        let gate = crate::directory::resolve("", "gate_able", &directory).unwrap();
        assert_eq!((gate.axis.as_str(), gate.target), ("gate_able", Target::BridgeValue(BridgeRecord::Value)));
        assert_eq!(crate::directory::resolve("", "m1_able", &directory).map(|p| p.target), Some(Target::Able));
    }

    #[test]
    fn name_reads_as_the_record_name_the_client_knows() {
        let mut circuit = Circuit::new("bl:");
        let directory = OneAxis { fetched: true };
        let created =
            request(&mut circuit, &directory, Header::new(command::CREATE_CHAN, 0, 0, 7, 13), b"bl:m1.NAME\0");
        let sid = created[1].0.p2;
        let read = request(&mut circuit, &directory, Header::new(command::READ_NOTIFY, 0, 1, sid, 99), &[]);
        assert_eq!(read[0].1[..6], *b"bl:m1\0");
    }

    #[test]
    fn writes_become_requests_and_their_outcomes_replies() {
        let mut circuit = Circuit::new("bl:");
        let directory = OneAxis { fetched: true };
        let created = request(&mut circuit, &directory, Header::new(command::CREATE_CHAN, 0, 0, 1, 13), b"bl:m1\0");
        let sid = created[1].0.p2;
        let rbv = request(&mut circuit, &directory, Header::new(command::CREATE_CHAN, 0, 0, 2, 13), b"bl:m1.RBV\0");
        assert_eq!(rbv[0].0.p2, 1, "RBV is read-only");
        let rbv_sid = rbv[1].0.p2;

        request(&mut circuit, &directory, Header::new(command::WRITE_NOTIFY, 6, 1, sid, 42), &4.0f64.to_be_bytes());
        let Some(Request::Write { pv, text, wait, hold, answer }) = circuit.poll_request() else { panic!("no write") };
        assert_eq!((pv.name("bl:"), text.as_str(), wait, hold), ("bl:m1.VAL".into(), "4", true, false));
        let refused = |kind| WriteEnd::Refused(zmotor_msgs::Refusal { kind, message: "words".into() });
        circuit.write_done(answer, refused(zmotor_msgs::RefusalKind::Busy), &directory);
        let failed = messages(&circuit.poll_transmit().unwrap());
        assert_eq!((failed[0].0.command, failed[0].0.p1, failed[0].0.p2), (command::WRITE_NOTIFY, 160, 42));
        // A limit violation is a put the record took, as an IOC answers it: LVIO tells.
        request(&mut circuit, &directory, Header::new(command::WRITE_NOTIFY, 6, 1, sid, 43), &500f64.to_be_bytes());
        let Some(Request::Write { answer, .. }) = circuit.poll_request() else { panic!("no write") };
        circuit.write_done(answer, refused(zmotor_msgs::RefusalKind::LimitViolation), &directory);
        let taken = messages(&circuit.poll_transmit().unwrap());
        assert_eq!((taken[0].0.p1, taken[0].0.p2), (1, 43), "ECA_NORMAL");
        let denied = WriteEnd::Unanswered { denied: true, why: "silence".into() };
        assert_eq!(denied.eca_code(), 376, "ECA_NOWTACCESS: access control answers nothing");
        assert_eq!(refused(zmotor_msgs::RefusalKind::ReadOnly).eca_code(), 376);
        assert_eq!(refused(zmotor_msgs::RefusalKind::Disabled).eca_code(), 1);
        assert_eq!(WriteEnd::Unanswered { denied: false, why: "gone".into() }.eca_code(), 160);

        let refused = request(&mut circuit, &directory, Header::new(command::WRITE, 6, 1, rbv_sid, 3), &[0; 8]);
        assert_eq!((refused[0].0.command, refused[0].0.p2), (command::ERROR, 376), "ECA_NOWTACCESS");
        assert!(codec::text(&refused[0].1[16..]).contains("read-only"));
        assert_eq!(circuit.poll_request(), None, "nothing is written to a read-only field");
    }

    #[test]
    fn alarm_acknowledgements_are_writes_of_ackt_and_acks_on_writable_channels_and_read_with_stsack() {
        let mut circuit = Circuit::new("");
        let directory = OneAxis { fetched: true };
        let rbv = request(&mut circuit, &directory, Header::new(command::CREATE_CHAN, 0, 0, 2, 13), b"m1.RBV\0");
        let rbv_sid = rbv[1].0.p2;
        let val = request(&mut circuit, &directory, Header::new(command::CREATE_CHAN, 0, 0, 4, 13), b"m1\0");
        let sid = val[1].0.p2;
        // Not on a channel one may not write, as rsrv checks its access.
        let refused = request(
            &mut circuit,
            &directory,
            Header::new(command::WRITE_NOTIFY, 36, 1, rbv_sid, 8),
            &2u16.to_be_bytes(),
        );
        assert_eq!((refused[0].0.command, refused[0].0.p1), (command::WRITE_NOTIFY, 376), "ECA_NOWTACCESS");
        assert_eq!(circuit.poll_request(), None);
        // DBR_PUT_ACKS (36) on the record's channel, as ALH writes it (a severity beyond INVALID
        // acknowledges INVALID).
        request(&mut circuit, &directory, Header::new(command::WRITE, 36, 1, sid, 1), &7u16.to_be_bytes());
        let Some(Request::Write { pv, text, wait, answer, .. }) = circuit.poll_request() else { panic!("no write") };
        assert_eq!((pv.name(""), text.as_str(), wait), ("m1.ACKS".into(), "3", false));
        circuit.write_done(answer, WriteEnd::Done, &directory);
        request(&mut circuit, &directory, Header::new(command::WRITE_NOTIFY, 35, 1, sid, 2), &0u16.to_be_bytes());
        let Some(Request::Write { pv, text, wait, answer, .. }) = circuit.poll_request() else { panic!("no write") };
        assert_eq!((pv.name(""), text.as_str(), wait), ("m1.ACKT".into(), "0", false));
        circuit.write_done(answer, WriteEnd::Done, &directory);
        let notified = messages(&circuit.poll_transmit().unwrap());
        assert_eq!((notified[0].0.command, notified[0].0.p1, notified[0].0.p2), (command::WRITE_NOTIFY, 1, 2));
        // `_able` is a bo of its own: nothing of the motor's is acknowledged through it.
        let able = request(&mut circuit, &directory, Header::new(command::CREATE_CHAN, 0, 0, 3, 13), b"m1_able\0");
        let able_sid = able[1].0.p2;
        let done = request(
            &mut circuit,
            &directory,
            Header::new(command::WRITE_NOTIFY, 36, 1, able_sid, 4),
            &3u16.to_be_bytes(),
        );
        assert_eq!((done[0].0.command, done[0].0.p1, done[0].0.p2), (command::WRITE_NOTIFY, 1, 4));
        assert_eq!(circuit.poll_request(), None);
        // DBR_STSACK_STRING (37): status, severity, ACKT, ACKS, then the value as text.
        let read = request(&mut circuit, &directory, Header::new(command::READ_NOTIFY, 37, 1, sid, 3), &[]);
        let words: Vec<u16> = read[0].1[..8].chunks(2).map(|w| u16::from_be_bytes([w[0], w[1]])).collect();
        assert_eq!(words, [0, 0, 1, 0]);
        assert_eq!(&read[0].1[8..12], b"2.50");
        // A change of ACKS is an alarm event to an STSACK subscriber (DBE_ALARM).
        let mut add = vec![0; 16];
        add[12..14].copy_from_slice(&4u16.to_be_bytes());
        assert_eq!(request(&mut circuit, &directory, Header::new(command::EVENT_ADD, 37, 1, sid, 9), &add).len(), 1);
        circuit.handle_change("m1", Target::Field(Field::ACKS), &directory);
        circuit.flush_alarms(&directory);
        assert_eq!(messages(&circuit.poll_transmit().unwrap())[0].0.p2, 9);
    }

    #[test]
    fn a_read_after_a_write_of_its_axis_is_answered_once_the_write_is_taken() {
        // caput then caget, on one circuit: an IOC processes the put before it reads.
        let mut circuit = Circuit::new("");
        let directory = OneAxis { fetched: true };
        let val = request(&mut circuit, &directory, Header::new(command::CREATE_CHAN, 0, 0, 1, 13), b"m1\0");
        let velo = request(&mut circuit, &directory, Header::new(command::CREATE_CHAN, 0, 0, 2, 13), b"m1.VELO\0");
        let (val, velo) = (val[1].0.p2, velo[1].0.p2);
        let written = request(&mut circuit, &directory, Header::new(command::WRITE, 6, 1, val, 1), &4f64.to_be_bytes());
        assert!(written.is_empty());
        let Some(Request::Write { wait: false, answer, .. }) = circuit.poll_request() else { panic!("no write") };
        assert!(request(&mut circuit, &directory, Header::new(command::READ_NOTIFY, 6, 1, velo, 7), &[]).is_empty());
        circuit.write_done(answer, WriteEnd::Done, &directory);
        let read = messages(&circuit.poll_transmit().unwrap());
        assert_eq!((read.len(), read[0].0.command, read[0].0.p2), (1, command::READ_NOTIFY, 7));
        let again = request(&mut circuit, &directory, Header::new(command::READ_NOTIFY, 6, 1, velo, 8), &[]);
        assert_eq!(again[0].0.p2, 8, "no write under way: read at once");
        // Writes that keep coming hold a read back only until those before it are taken.
        let write = |circuit: &mut Circuit, value: f64| {
            let header = Header::new(command::WRITE, 6, 1, velo, 1);
            request(circuit, &directory, header, &value.to_be_bytes());
            let Some(Request::Write { answer, .. }) = circuit.poll_request() else { panic!("no write") };
            answer
        };
        let first = write(&mut circuit, 1.0);
        assert!(request(&mut circuit, &directory, Header::new(command::READ_NOTIFY, 6, 1, velo, 11), &[]).is_empty());
        let second = write(&mut circuit, 2.0);
        circuit.write_done(first, WriteEnd::Done, &directory);
        let read = messages(&circuit.poll_transmit().unwrap());
        assert_eq!(read[0].0.p2, 11, "answered once the write before it was taken, the later one under way");
        circuit.write_done(second, WriteEnd::Done, &directory);
        // A put-callback that waits for the motion's end holds no read back.
        let notify = Header::new(command::WRITE_NOTIFY, 6, 1, val, 9);
        request(&mut circuit, &directory, notify, &5f64.to_be_bytes());
        assert!(matches!(circuit.poll_request(), Some(Request::Write { wait: true, .. })));
        let during = request(&mut circuit, &directory, Header::new(command::READ_NOTIFY, 6, 1, velo, 10), &[]);
        assert_eq!(during[0].0.p2, 10);
    }

    #[test]
    fn a_monitor_made_before_the_values_arrive_gets_its_first_event_then_alarms_and_held_events() {
        let mut circuit = Circuit::new("");
        let mut directory = OneAxis { fetched: false };
        let created = request(&mut circuit, &directory, Header::new(command::CREATE_CHAN, 0, 0, 1, 13), b"m1.RBV\0");
        let sid = created[1].0.p2;
        // DBR_TIME_DOUBLE, DBE_VALUE | DBE_ALARM: nothing yet, the axis is fetched.
        let mut add = vec![0; 16];
        add[12..14].copy_from_slice(&5u16.to_be_bytes());
        assert!(request(&mut circuit, &directory, Header::new(command::EVENT_ADD, 20, 1, sid, 9), &add).is_empty());
        directory.fetched = true;
        // The first change of the axis, whichever field, brings the first event.
        circuit.handle_change("m1", Target::Field(Field::DESC), &directory);
        assert_eq!(messages(&circuit.poll_transmit().unwrap())[0].0.p2, 9);
        circuit.handle_change("m1", Target::Field(Field::DESC), &directory);
        assert_eq!(circuit.poll_transmit(), None, "DESC is not RBV's");
        // One processing's alarm posts (SEVR, STAT, ACKS) make one event, as an IOC's.
        for field in [Field::SEVR, Field::STAT, Field::ACKS] {
            circuit.handle_change("m1", Target::Field(field), &directory);
        }
        assert_eq!(circuit.poll_transmit(), None, "owed until the changes told so far are handled");
        circuit.flush_alarms(&directory);
        assert_eq!(messages(&circuit.poll_transmit().unwrap()).len(), 1, "an alarm change reaches DBE_ALARM");
        circuit.flush_alarms(&directory);
        assert_eq!(circuit.poll_transmit(), None, "once");
        // So do they to a DBR_CTRL subscriber, whose metadata holds the alarm too.
        let mut add = vec![0; 16];
        add[12..14].copy_from_slice(&5u16.to_be_bytes());
        let first = request(&mut circuit, &directory, Header::new(command::EVENT_ADD, 34, 1, sid, 10), &add);
        assert_eq!(first.len(), 1);
        for field in [Field::SEVR, Field::STAT, Field::ACKS] {
            circuit.handle_change("m1", Target::Field(field), &directory);
        }
        assert_eq!(circuit.poll_transmit(), None);
        assert!(circuit.alarms_due());
        circuit.flush_alarms(&directory);
        let events: Vec<u32> = messages(&circuit.poll_transmit().unwrap()).iter().map(|(h, _)| h.p2).collect();
        assert_eq!(events, [9, 10], "one each");
        // A lost stream's repost clears what was owed (it posts everything).
        circuit.handle_change("m1", Target::Field(Field::STAT), &directory);
        circuit.repost(&directory);
        circuit.flush_alarms(&directory);
        assert_eq!(messages(&circuit.poll_transmit().unwrap()).len(), 2, "the repost's two, nothing more");
        // An alarm owed is carried by a value's event that comes before it is posted.
        circuit.handle_change("m1", Target::Field(Field::STAT), &directory);
        circuit.handle_change("m1", Target::Field(Field::RBV), &directory);
        circuit.flush_alarms(&directory);
        assert_eq!(messages(&circuit.poll_transmit().unwrap()).len(), 2, "one event each, the value's");
        // Events held back by EVENTS_OFF are posted at EVENTS_ON.
        request(&mut circuit, &directory, Header::new(command::EVENTS_OFF, 0, 0, 0, 0), &[]);
        circuit.handle_change("m1", Target::Field(Field::RBV), &directory);
        assert_eq!(circuit.poll_transmit(), None);
        let resumed = request(&mut circuit, &directory, Header::new(command::EVENTS_ON, 0, 0, 0, 0), &[]);
        assert_eq!((resumed.len(), resumed[0].0.command), (2, command::EVENT_ADD), "each subscription once");
        // An unknown channel id is named as such.
        let unknown = request(&mut circuit, &directory, Header::new(command::READ_NOTIFY, 6, 1, 999, 1), &[]);
        assert_eq!((unknown[0].0.command, unknown[0].0.p2), (command::ERROR, 410));
    }

    /// m1 moving: its RBV as set, ADEL 0.5 mm, every other field 0.
    struct Moving {
        rbv: f64,
    }

    impl Directory for Moving {
        fn is_live(&self, axis: &str) -> bool {
            OneAxis { fetched: true }.is_live(axis)
        }

        fn bridge_record(&self, _: &str) -> Option<BridgeRecord> {
            None
        }

        fn snapshot(&self, pv: &Pv) -> Option<Snapshot> {
            let value = match pv.target {
                Target::Field(Field::RBV) => self.rbv,
                Target::Field(Field::ADEL) => 0.5,
                _ => 0.0,
            };
            let mut snapshot = OneAxis { fetched: true }.snapshot(pv)?;
            snapshot.value = Value::Float(value);
            Some(snapshot)
        }
    }

    #[test]
    fn an_archive_monitor_of_rbv_gets_the_moves_past_adel_a_value_monitor_every_one() {
        let mut circuit = Circuit::new("");
        let mut directory = Moving { rbv: 0.0 };
        let created = request(&mut circuit, &directory, Header::new(command::CREATE_CHAN, 0, 0, 1, 13), b"m1.RBV\0");
        let sid = created[1].0.p2;
        // DBR_DOUBLE, subscription 1 with DBE_LOG (an archiver), 2 with DBE_VALUE (a display).
        for (subid, mask) in [(1, 2u16), (2, 1u16)] {
            let mut add = vec![0; 16];
            add[12..14].copy_from_slice(&mask.to_be_bytes());
            let first = request(&mut circuit, &directory, Header::new(command::EVENT_ADD, 6, 1, sid, subid), &add);
            assert_eq!(first.len(), 1, "the current value first");
        }
        let mut seen = Vec::new();
        for rbv in [0.2, 0.4, 0.6, 0.8, 1.2, 1.3] {
            directory.rbv = rbv;
            circuit.handle_change("m1", Target::Field(Field::RBV), &directory);
            let events = messages(&circuit.poll_transmit().unwrap_or_default());
            seen.push(events.iter().map(|(header, _)| header.p2).collect::<Vec<_>>());
        }
        // Past 0.5 from the last archived (0, then 0.6, then 1.2); the display every time.
        assert_eq!(seen, [vec![2], vec![2], vec![1, 2], vec![2], vec![1, 2], vec![2]]);
        // An alarm's event (to a subscriber of DBE_LOG and DBE_ALARM) does not move the
        // archiver's last value: 1.6 is past 0.5 from 1.0 only if the alarm's 1.5 was not taken.
        let mut add = vec![0; 16];
        add[12..14].copy_from_slice(&(2u16 | 4).to_be_bytes());
        directory.rbv = 1.0;
        // DBR_STS_DOUBLE: an alarm's event reaches a type that carries the alarm.
        request(&mut circuit, &directory, Header::new(command::EVENT_ADD, 13, 1, sid, 3), &add);
        directory.rbv = 1.5;
        circuit.handle_change("m1", Target::Field(Field::SEVR), &directory);
        circuit.flush_alarms(&directory);
        let alarmed = messages(&circuit.poll_transmit().unwrap_or_default());
        assert!(alarmed.iter().any(|(header, _)| header.p2 == 3), "{alarmed:?}");
        directory.rbv = 1.6;
        circuit.handle_change("m1", Target::Field(Field::RBV), &directory);
        let events = messages(&circuit.poll_transmit().unwrap_or_default());
        assert!(events.iter().any(|(header, _)| header.p2 == 3), "{events:?}");
    }

    #[test]
    fn searches_are_answered_for_live_channels_only() {
        let directory = OneAxis { fetched: false };
        let mut datagram = codec::encode(Header::new(command::VERSION, 0, 13, 0, 0), &[]);
        datagram.extend(codec::encode(Header::new(command::SEARCH, 5, 13, 11, 21), b"m1.RBV\0"));
        datagram.extend(codec::encode(Header::new(command::SEARCH, 5, 13, 12, 12), b"m2\0"));
        let answer = messages(&search::answer("", &datagram, 5064, &directory).unwrap());
        assert_eq!(answer.len(), 2);
        assert_eq!((answer[1].0.command, answer[1].0.data_type, answer[1].0.p2), (command::SEARCH, 5064, 21));
        let unknown = codec::encode(Header::new(command::SEARCH, 5, 13, 12, 12), b"m2\0");
        assert_eq!(search::answer("", &unknown, 5064, &directory), None);
    }
}
