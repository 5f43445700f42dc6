//! Input links written at run time are followed at once, as the record follows them: a DOL and
//! OMSL closed_loop written over Zenoh drive the axis from the linked key; RDBL switched at run
//! time changes where the readback comes from; a link change that cannot be wired is refused and
//! changes nothing. A calc link processed by a key (a forward link into it) writes at each write
//! of that key, not at start. Nothing moves from a connection: what a link finds when it
//! connects or its source comes back drives no motor.

use std::time::Duration;
use zmotor_msgs::{Field, Value};
use zmotor_tests::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_dol_written_at_run_time_drives_the_axis_in_closed_loop() {
    let node = TestNode::start(vec![fast_axis("m1")]).await;
    let client = node.client().await;
    confirmed_write(&client, &node.key("m1", Field::DOL), "lab/setpoint", PATIENCE).await.unwrap();
    confirmed_write(&client, &node.key("m1", Field::OMSL), "closed_loop", PATIENCE).await.unwrap();
    let mut rec = Recorder::new(&node, &client, "motor/m1/*").await;
    // Twelve defined positions put on the linked key, each reached before the next.
    for (i, position) in [1.0, 2.5, -3.0, 10.0, 0.5, 7.25, -1.0, 4.0, 4.5, -8.0, 6.0, 2.0].into_iter().enumerate() {
        put_text(&client, "lab/setpoint", &position.to_string()).await;
        rec.wait_for("RBV", |v| v.as_f64().is_some_and(|x| (x - position).abs() < 1e-6)).await;
        rec.wait_for("DMOV", |v| *v == int(1)).await;
        assert_eq!(get_f64(&client, &node.key("m1", Field::VAL)).await, position, "position {i}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rdbl_switched_at_run_time_changes_where_the_readback_comes_from() {
    let mut plan = fast_axis("m1");
    plan.fields.urip = 1;
    plan.fields.rres = 1.0;
    plan.fields.rdbl = "lab/encoder1".into();
    let node = TestNode::start(vec![plan]).await;
    let client = node.client().await;
    let rbv = node.key("m1", Field::RBV);
    put_text(&client, "lab/encoder1", "0.25").await;
    wait_until(&client, &rbv, 0.25).await;
    confirmed_write(&client, &node.key("m1", Field::RDBL), "lab/encoder2", PATIENCE).await.unwrap();
    put_text(&client, "lab/encoder2", "0.5").await;
    wait_until(&client, &rbv, 0.5).await;
    // The old key is no longer followed: its value, written before the new key's, never shows.
    let mut readbacks = Recorder::new(&node, &client, &rbv).await;
    put_text(&client, "lab/encoder1", "0.9").await;
    put_text(&client, "lab/encoder2", "0.6").await;
    readbacks.wait_for("RBV", |v| *v == Value::Float(0.6)).await;
    assert!(!readbacks.values("RBV").contains(&Value::Float(0.9)), "{:?}", readbacks.values("RBV"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_link_change_that_cannot_be_wired_is_refused_and_changes_nothing() {
    let mut plan = fast_axis("m1");
    plan.fields.dol = "lab/setpoint".into();
    let node = TestNode::start(vec![plan]).await;
    let client = node.client().await;
    let dol = node.key("m1", Field::DOL);
    for (key, why) in [
        ("a//b", "DOL: 'a//b' is not a plain key"),
        ("x/*y", "DOL: 'x/*y' is not a plain key"),
        ("motor/m1/RBV", "DOL: motor/m1/RBV: axis 'm1' would link to its own RBV"),
        ("motor/m2/NOPE", "DOL: motor/m2/NOPE: 'NOPE' is not a field of a motor"),
    ] {
        let err = confirmed_write(&client, &dol, key, PATIENCE).await.unwrap_err();
        assert!(err.starts_with(why), "{key}: {err}");
    }
    let err = confirmed_write(&client, &node.key("m1", Field::OUT), "motor/m2/RBV", PATIENCE).await.unwrap_err();
    assert!(err.starts_with("OUT: motor/m2/RBV: RBV is read-only"), "{err}");
    assert_eq!(get_value(&client, &dol).await, Value::Text("lab/setpoint".into()));
    // Still following the link it had.
    confirmed_write(&client, &node.key("m1", Field::OMSL), "closed_loop", PATIENCE).await.unwrap();
    let mut rec = Recorder::new(&node, &client, "motor/m1/DMOV").await;
    put_text(&client, "lab/setpoint", "3").await;
    rec.wait_for("DMOV", |v| *v == int(1)).await;
    wait_until(&client, &node.key("m1", Field::RBV), 3.0).await;
}

/// A launch text of axis m1, fast (MRES 0.001, VELO 100), its fields table open, and `rest`.
fn with_fast_m1(rest: &str) -> String {
    fast_axis_text("m1", rest)
}

/// A launch file's fast simulated axis `name`, its fields followed by `rest`.
fn fast_axis_text(name: &str, rest: &str) -> String {
    format!("[[axis]]\nname = \"{name}\"\n[axis.fields]\nMRES = 0.001\nVELO = 100.0{rest}")
}

/// Poll a key until it reads `expected` (bounded by PATIENCE), whether or not anything answers
/// meanwhile (a node starting).
async fn wait_until(client: &zenoh::Session, key: &str, expected: f64) {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    loop {
        let replies = client.get(key).timeout(Duration::from_millis(500)).await.unwrap();
        let value = match replies.recv_async().await {
            Ok(reply) => reply.result().ok().and_then(|s| zmotor_msgs::decode_cbor_value(&s.payload().to_bytes()).ok()),
            Err(_) => None,
        };
        let value = value.and_then(|v| v.as_f64());
        if value.is_some_and(|v| (v - expected).abs() < 1e-9) {
            return;
        }
        assert!(tokio::time::Instant::now() < deadline, "{key} is {value:?}, expected {expected}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_soft_motor_whose_readback_node_goes_is_stopped_and_moves_no_more() {
    // The driven stage `lin` is played by this test's session: its liveliness token (as a node
    // serving it declares), its readback and done flag; the soft motor drives it by its links.
    let mut plan = fast_axis("soft");
    plan.driver = zmotor_core::DriverPlan::Soft;
    plan.fields.dtyp = "Soft Channel".into();
    plan.fields.out = "motor/lin/VAL".into();
    plan.fields.rdbl = "motor/lin/RBV".into();
    plan.fields.dinp = "motor/lin/DMOV".into();
    plan.fields.stoo = "motor/lin/STOP".into();
    (plan.fields.urip, plan.fields.rres, plan.fields.rtry, plan.fields.ntm) = (1, 1.0, 0, 0);
    let node = TestNode::start(vec![plan]).await;
    let stage = node.client().await;
    let driven = stage.declare_subscriber("motor/lin/VAL").await.unwrap();
    let stopped = stage.declare_subscriber("motor/lin/STOP").await.unwrap();
    let client = node.client().await;
    let mut rec = Recorder::new(&node, &client, "motor/soft/*").await;
    let token = stage.liveliness().declare_token("motor/lin").await.unwrap();
    put_text(&stage, "motor/lin/DMOV", "1").await;
    put_text(&stage, "motor/lin/RBV", "0.5").await;
    rec.wait_for("RBV", |v| v.as_f64().is_some_and(|x| (x - 0.5).abs() < 1e-9)).await;
    confirmed_write(&client, &node.key("soft", Field::VAL), "1", PATIENCE).await.unwrap();
    tokio::time::timeout(PATIENCE, driven.recv_async()).await.expect("the move drives the stage").unwrap();
    put_text(&stage, "motor/lin/DMOV", "0").await;
    put_text(&stage, "motor/lin/RBV", "0.7").await;
    rec.wait_for("RBV", |v| v.as_f64().is_some_and(|x| (x - 0.7).abs() < 1e-9)).await;
    // The stage's node goes: the soft motor stops it, as a record whose RDBL disconnected.
    drop(token);
    tokio::time::timeout(PATIENCE, stopped.recv_async()).await.expect("STOP written to STOO").unwrap();
    // And drives it no more while its readback cannot be read.
    let _ = confirmed_write(&client, &node.key("soft", Field::VAL), "2", PATIENCE).await;
    let moved = tokio::time::timeout(Duration::from_millis(500), driven.recv_async()).await;
    assert!(moved.is_err(), "a move drove the stage from a readback nobody serves: {moved:?}");
}

/// SDIS, as an interlock wires it: while the linked key reads DISV the record is disabled (a
/// target is refused, nothing moves; STAT DISABLE at DISS); once it reads otherwise, a target
/// moves.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_sdis_link_disables_the_record_while_its_key_reads_disv() {
    let mut plan = fast_axis("m1");
    plan.fields.sdis = "lab/interlock".into();
    plan.fields.diss = zmotor_msgs::menus::severity::MAJOR;
    let node = TestNode::start(vec![plan]).await;
    let client = node.client().await;
    put_text(&client, "lab/interlock", "1").await;
    wait_until(&client, &node.key("m1", Field::DISA), 1.0).await;
    // A setting processes the record: the alarm says it is disabled.
    confirmed_write(&client, &node.key("m1", Field::HLSV), "MINOR", PATIENCE).await.unwrap();
    let (stat, sevr) = (
        get_value(&client, &node.key("m1", Field::STAT)).await,
        get_value(&client, &node.key("m1", Field::SEVR)).await,
    );
    assert_eq!((stat, sevr), (int(18), int(2)), "DISABLE, MAJOR");
    let refused = confirmed_write(&client, &node.key("m1", Field::VAL), "2", PATIENCE).await.unwrap_err();
    assert!(refused.contains("the record is disabled (DISA = DISV); nothing changed"), "{refused}");
    assert_eq!(get_f64(&client, &node.key("m1", Field::VAL)).await, 0.0);
    // A client's DISA 0 does not outlast the interlock's value.
    confirmed_write(&client, &node.key("m1", Field::DISA), "0", PATIENCE).await.unwrap();
    assert!(confirmed_write(&client, &node.key("m1", Field::VAL), "2", PATIENCE).await.is_err());
    // The interlock released: a target moves.
    put_text(&client, "lab/interlock", "0").await;
    wait_until(&client, &node.key("m1", Field::DISA), 0.0).await;
    let mut rec = Recorder::new(&node, &client, "motor/m1/*").await;
    confirmed_write(&client, &node.key("m1", Field::VAL), "2", PATIENCE).await.unwrap();
    rec.wait_for("RBV", |v| *v == Value::Float(2.0)).await;
    rec.wait_for("DMOV", |v| *v == int(1)).await;
}

/// A calc link processed by a value's key (an EPICS forward link into it, as a `.db`'s ao FLNK
/// imports): nothing is written when it starts, though the value is there; each write of the
/// value is, computed with the written value.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_calc_processed_by_a_value_writes_at_each_write_of_it_and_not_at_start() {
    let text = with_fast_m1(
        r#"
[[value]]
name = "goal"
value = 3.0
[[calc]]
name = "drive"
expression = "A*2"
inputs = { A = { key = "bridge/goal/VAL", mode = "npp" } }
output = "motor/m1/VAL"
processed_by = ["bridge/goal/VAL"]
"#,
    );
    let node = TestNode::launch(&text).await;
    let client = node.client().await;
    let mut m1 = Recorder::new(&node, &client, "motor/m1/VAL").await;
    // The calc follows its keys once the node serves; it reads its input's value meanwhile.
    assert_eq!(get_value(&client, "bridge/goal/VAL").await, Value::Float(3.0));
    m1.drain_for(Duration::from_millis(500)).await;
    assert!(m1.values("VAL").is_empty(), "written at start: {:?}", m1.values("VAL"));
    assert_eq!(get_f64(&client, &node.key("m1", Field::VAL)).await, 0.0);
    put_text(&client, "bridge/goal/VAL", "1.25").await;
    let val = m1.wait_for("VAL", |v| v.as_f64().is_some()).await;
    assert_eq!(val.as_f64(), Some(2.5), "A*2 of the value written");
}

/// A motor's forward link into a calc (FLNK on the calc's PROC, which the calc is processed by):
/// nothing at start; at the end of a move, one write, computed from the readback it ended at.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_motors_forward_link_processes_a_calc_once_with_the_readback_it_ended_at() {
    let text = with_fast_m1(
        r#"
FLNK = "bridge/after/PROC"
[[calc]]
name = "after"
expression = "A*10"
inputs = { A = { key = "motor/m1/RBV", mode = "npp" } }
output = "bridge/tally/VAL"
processed_by = ["bridge/after/PROC"]
[[value]]
name = "tally"
value = 7.0
"#,
    );
    let node = TestNode::launch(&text).await;
    let client = node.client().await;
    // The calc's output is a plain write (no state marker), as a calcout's OUT.
    let after = client.declare_subscriber("bridge/tally/VAL").await.unwrap();
    node.until_subscribed("bridge/tally/VAL").await;
    // Nothing at start: the value holds what it started with (A*10 of the readback would be 0).
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert_eq!(get_value(&client, "bridge/tally/VAL").await, Value::Float(7.0));
    let _ = confirmed_write(&client, "motor/m1/VAL?wait", "2.5", PATIENCE).await.unwrap();
    let first = tokio::time::timeout(PATIENCE, after.recv_async()).await.expect("a write").unwrap();
    assert_eq!(first.payload().try_to_string().unwrap(), "25", "A*10 of the readback the move ended at");
    tokio::time::sleep(Duration::from_millis(300)).await;
    let more: Vec<_> = after.drain().map(|s| s.payload().try_to_string().unwrap().into_owned()).collect();
    assert!(more.is_empty(), "one write a move's end, then: {more:?}");
}

/// A calc of constants only (the motor record manual's SoftMotorEx.db: `height`, CALC "1000",
/// read by another calc's PP input, which processes it first on an IOC) serves its result from
/// the start, and another calc reads it; one whose result goes to a motor writes nothing unasked.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_calc_of_constants_only_serves_its_value_from_the_start_and_moves_nothing() {
    let text = with_fast_m1(
        r#"
[[calc]]
name = "height"
expression = "1000"
output = "bridge/height/VAL"
[[calc]]
name = "pushes"
expression = "5"
output = "motor/m1/VAL"
[[calc]]
name = "drive"
expression = "A+B"
inputs = { A = "lab/angle", B = { key = "bridge/height/VAL", mode = "npp" } }
output = "bridge/sum/VAL"
"#,
    );
    let node = TestNode::launch(&text).await;
    let client = node.client().await;
    let sum = client.declare_subscriber("bridge/sum/VAL").await.unwrap();
    node.until_subscribed("bridge/sum/VAL").await;
    assert_eq!(get_value(&client, "bridge/height/VAL").await, Value::Float(1000.0));
    put_text(&client, "lab/angle", "1").await;
    let first = tokio::time::timeout(PATIENCE, sum.recv_async()).await.expect("a result").unwrap();
    assert_eq!(first.payload().try_to_string().unwrap(), "1001", "A + the constant calc's result");
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert_eq!(get_f64(&client, &node.key("m1", Field::VAL)).await, 0.0, "a constant calc moved the motor");
}

/// A soft motor whose readback link reads a value holder of the same launch (softMotorTest.db's
/// FeedBack ao) finds it at once: the holder answers before the axis's links ask.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_soft_motor_reads_a_value_holder_of_its_own_launch_from_the_start() {
    let text = r#"
[[axis]]
name = "theta"
driver = "soft"
[axis.fields]
URIP = "Yes"
MRES = 0.001
RRES = 1.0
RDBL = "bridge/feedback/VAL"
OUT = "bridge/position/VAL"
[[value]]
name = "feedback"
value = 2.5
[[value]]
name = "position"
"#;
    let node = TestNode::launch(text).await;
    let client = node.client().await;
    wait_until(&client, &node.key("theta", Field::RBV), 2.5).await;
    let written = confirmed_write(&client, &node.key("theta", Field::VAL), "4", PATIENCE).await;
    assert!(written.is_ok(), "the move was refused: {written:?}");
    wait_until(&client, "bridge/position/VAL", 4.0).await;
}

/// motorApp's sumDiff2D.db (two transforms, a dfanout and a calcout) with its two soft motors:
/// moving SUM and DIFF moves the real motors where the drive transform puts them, computed from
/// the soft motors' dial values read when it processes (their output links' writes process it
/// before their DVAL is posted); their readbacks come back through the readback transform.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sum_and_diff_soft_motors_move_two_real_motors_through_transform_records() {
    let database = include_str!("../../launch/sum-diff.db");
    let node = TestNode::launch_database(database).await;
    let client = node.client().await;
    let rbv = |axis: &str| node.key(axis, Field::RBV);
    // SUM = (m1 C1 + m2 C2) / (C1 + C2), DIFF = (m1 - m2) E: with C1 1, C2 3, E 2, SUM 2 and
    // DIFF 0.8 put m1 at 2 + 0.8 * 3 / 8 = 2.3 and m2 at 2 - 0.8 / 8 = 1.9.
    confirmed_write(&client, &node.key("sum", Field::VAL), "2", PATIENCE).await.unwrap();
    wait_until(&client, &rbv("m1"), 2.0).await;
    wait_until(&client, &rbv("m2"), 2.0).await;
    confirmed_write(&client, &node.key("diff", Field::VAL), "0.8", PATIENCE).await.unwrap();
    wait_until(&client, &rbv("m1"), 2.3).await;
    wait_until(&client, &rbv("m2"), 1.9).await;
    // The soft motors read back through the readback transform, and end their moves.
    wait_until(&client, &rbv("sum"), 2.0).await;
    wait_until(&client, &rbv("diff"), 0.8).await;
    wait_until(&client, &node.key("sum", Field::DMOV), 1.0).await;
    wait_until(&client, &node.key("diff", Field::DMOV), 1.0).await;
    // A transform's field on its own key answers reads (a soft motor connecting later reads it).
    assert!((get_f64(&client, "bridge/tReadback/G").await - 2.0).abs() < 1e-9);
    assert!((get_f64(&client, "bridge/tReadback/H").await - 0.8).abs() < 1e-9);
}

/// A motor in closed loop on a value holder of its own launch: the value found when the link
/// connects moves nothing (no motion from a connection); the next value put there drives it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_closed_loop_dol_moves_nothing_at_start_and_follows_the_next_update() {
    let text = with_fast_m1(
        r#"
OMSL = "closed_loop"
DOL = "bridge/setpoint/VAL"
[[value]]
name = "setpoint"
value = 3.0
"#,
    );
    let node = TestNode::launch(&text).await;
    let client = node.client().await;
    assert_eq!(get_value(&client, "bridge/setpoint/VAL").await, Value::Float(3.0));
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert_eq!(get_f64(&client, &node.key("m1", Field::VAL)).await, 0.0, "moved at start");
    assert_eq!(get_f64(&client, &node.key("m1", Field::DMOV)).await, 1.0);
    put_text(&client, "bridge/setpoint/VAL", "1.5").await;
    wait_until(&client, &node.key("m1", Field::RBV), 1.5).await;
}

/// An axis served by the test's own session, as a node would serve it: its liveliness token
/// and its readback, answered to reads and posted.
struct PlayedAxis {
    session: zenoh::Session,
    name: String,
    readback: std::sync::Arc<std::sync::Mutex<f64>>,
    /// Reads of its readback answered so far.
    answered: std::sync::Arc<std::sync::atomic::AtomicUsize>,
    _reads: zenoh::query::Queryable<()>,
    token: Option<zenoh::liveliness::LivelinessToken>,
}

impl PlayedAxis {
    async fn serve(session: zenoh::Session, name: &str, readback: f64) -> Self {
        let readback = std::sync::Arc::new(std::sync::Mutex::new(readback));
        let answered = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let (value, count, stamps) = (readback.clone(), answered.clone(), session.clone());
        let reads = session
            .declare_queryable(format!("motor/{name}/RBV"))
            .callback(move |query| {
                // Answered as a node answers: its state marker and its session's timestamp.
                let value = zmotor_msgs::encode_cbor(&Value::Float(*value.lock().unwrap()));
                let reply =
                    query.reply(query.key_expr().clone(), value).encoding(zenoh::bytes::Encoding::APPLICATION_CBOR);
                let reply = reply.attachment(zmotor_msgs::StateMarker::new(0, 0, 0).encode());
                let _ = zenoh::Wait::wait(reply.timestamp(stamps.new_timestamp()));
                count.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
            })
            .await
            .unwrap();
        Self { session, name: name.to_string(), readback, answered, _reads: reads, token: None }
    }

    /// Its token comes.
    async fn come(&mut self) {
        self.token = Some(self.session.liveliness().declare_token(format!("motor/{}", self.name)).await.unwrap());
    }

    /// Its token goes, and `node`'s session has seen it go.
    async fn go(&mut self, node: &TestNode) {
        self.token = None;
        let deadline = tokio::time::Instant::now() + PATIENCE;
        let token = format!("motor/{}", self.name);
        while node.session.liveliness().get(&token).await.unwrap().recv_async().await.is_ok() {
            assert!(tokio::time::Instant::now() < deadline, "{token} still seen by the node");
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    }

    /// Its readback changes: posted as a node posts it (its session's timestamp, a state marker).
    async fn post(&self, readback: f64) {
        *self.readback.lock().unwrap() = readback;
        let marker = zmotor_msgs::StateMarker::new(0, 0, 0).encode();
        let value = zmotor_msgs::encode_cbor(&Value::Float(readback));
        let put = self.session.put(format!("motor/{}/RBV", self.name), value).attachment(marker);
        put.encoding(zenoh::bytes::Encoding::APPLICATION_CBOR).timestamp(self.session.new_timestamp()).await.unwrap();
    }
}

/// Assert `axis`'s VAL is still `at`: nothing moved it on a value found.
async fn val_stays(client: &zenoh::Session, node: &TestNode, axis: &str, at: f64) {
    let val = get_f64(client, &node.key(axis, Field::VAL)).await;
    assert!((val - at).abs() < 1e-9, "{axis} moved on a value found: VAL {val}");
}

/// No move from a connection: a calc link writing into a motor (CP inputs on other axes'
/// readbacks) writes nothing on the values it finds when it connects, when an input's source
/// comes, or on what a source coming back posts first (the state it found), also when it came
/// back before the one gone was known gone; nor does a motor in closed loop on such a readback
/// move then. Each next update writes, and moves.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn links_into_motors_move_nothing_on_values_found_at_connect_or_at_a_sources_return() {
    let lead = TestNode::start(vec![fast_axis("lead")]).await;
    let lead_client = lead.client().await;
    confirmed_write(&lead_client, &lead.key("lead", Field::VAL), "2", PATIENCE).await.unwrap();
    wait_until(&lead_client, &lead.key("lead", Field::RBV), 2.0).await;
    let text = format!(
        "[zenoh]\nconnect = [\"{}\"]\n{}",
        lead.endpoint,
        with_fast_m1(&format!(
            "\n{}",
            fast_axis_text(
                "m2",
                r#"
OMSL = "closed_loop"
DOL = "motor/played/RBV"
[[calc]]
name = "follow"
expression = "A+B"
inputs = { A = "motor/lead/RBV", B = "motor/played/RBV" }
output = "motor/m1/VAL"
"#
            )
        ))
    );
    let node = TestNode::launch(&text).await;
    let client = node.client().await;
    let mut written = Recorder::new(&node, &client, "motor/*/VAL").await;
    written.drain_for(Duration::from_millis(500)).await;
    assert!(written.values("VAL").is_empty(), "written at connect: {:?}", written.values("VAL"));
    val_stays(&client, &node, "m1", 0.0).await;
    // The lead moves: its updates are events, and m1 follows.
    confirmed_write(&lead_client, &lead.key("lead", Field::VAL), "1", PATIENCE).await.unwrap();
    wait_until(&client, &node.key("m1", Field::RBV), 1.0).await;
    // A source comes: its value is found.
    let mut played = PlayedAxis::serve(node.client().await, "played", 0.5).await;
    played.come().await;
    written.drain_for(Duration::from_millis(500)).await;
    val_stays(&client, &node, "m1", 1.0).await;
    val_stays(&client, &node, "m2", 0.0).await;
    // It goes, and comes back with another value, posted before its token (a node's first poll).
    played.go(&node).await;
    played.post(0.7).await;
    played.come().await;
    written.drain_for(Duration::from_millis(500)).await;
    val_stays(&client, &node, "m1", 1.0).await;
    val_stays(&client, &node, "m2", 0.0).await;
    // Its next update is an event: both move.
    played.post(0.9).await;
    wait_until(&client, &node.key("m1", Field::RBV), 1.9).await;
    wait_until(&client, &node.key("m2", Field::RBV), 0.9).await;
    // It comes back on another session before its old token goes (a node restarted within its
    // lease; Zenoh tells neither the new token nor the old one's going): its first post is found
    // by its session.
    let mut restarted = PlayedAxis::serve(node.client().await, "played", 1.1).await;
    restarted.post(1.1).await;
    restarted.come().await;
    drop(played);
    written.drain_for(Duration::from_millis(500)).await;
    val_stays(&client, &node, "m1", 1.9).await;
    val_stays(&client, &node, "m2", 0.9).await;
    restarted.post(1.3).await;
    wait_until(&client, &node.key("m1", Field::RBV), 2.3).await;
    wait_until(&client, &node.key("m2", Field::RBV), 1.3).await;
}

/// A motor in closed loop on another axis of its own node (its DOL on that axis's VAL) follows
/// that axis's first move: the node's own axes do not come and go, their posts are updates.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_closed_loop_dol_on_an_axis_of_its_node_follows_its_first_move() {
    let m2 = fast_axis_text("m2", "\nOMSL = \"closed_loop\"\nDOL = \"motor/m1/VAL\"\n");
    let text = with_fast_m1(&format!("\n{m2}"));
    let node = TestNode::launch(&text).await;
    let client = node.client().await;
    confirmed_write(&client, &node.key("m1", Field::VAL), "1.5", PATIENCE).await.unwrap();
    wait_until(&client, &node.key("m2", Field::RBV), 1.5).await;
}

/// A calc record's value computed from what its links found (its node starting, or starting
/// again) is published as found: a calcout following it into a motor writes nothing then; an
/// update of the record's inputs writes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_calc_records_value_found_at_its_nodes_start_moves_no_motor_through_a_calcout() {
    let drive = "\n[[calc]]\nname = \"drive\"\nexpression = \"A\"\ninputs = { A = \"bridge/scaled/VAL\" }\noutput = \"motor/m1/VAL\"\n";
    let text = with_fast_m1(&format!("\n{}", fast_axis_text("lead", drive)));
    let node = TestNode::launch(&text).await;
    let client = node.client().await;
    confirmed_write(&client, &node.key("lead", Field::VAL), "2", PATIENCE).await.unwrap();
    wait_until(&client, &node.key("lead", Field::RBV), 2.0).await;
    let bridge_text = format!(
        "[zenoh]\nmode = \"peer\"\nlisten = []\nconnect = [\"{}\"]\n[[calc]]\nname = \"scaled\"\nexpression = \"A*2\"\n\
         inputs = {{ A = \"motor/lead/RBV\" }}\noutput = \"bridge/scaled/VAL\"\n",
        node.endpoint
    );
    let bridge = TestNode::launch(&bridge_text).await;
    wait_until(&client, "bridge/scaled/VAL", 4.0).await;
    tokio::time::sleep(Duration::from_millis(500)).await;
    val_stays(&client, &node, "m1", 0.0).await;
    // An update of the record's input: the calcout writes.
    confirmed_write(&client, &node.key("lead", Field::VAL), "1", PATIENCE).await.unwrap();
    wait_until(&client, &node.key("m1", Field::RBV), 2.0).await;
    // The record's node starts again after the lead moved: its first value is found.
    drop(bridge);
    confirmed_write(&client, &node.key("lead", Field::VAL), "1.5", PATIENCE).await.unwrap();
    wait_until(&client, &node.key("lead", Field::RBV), 1.5).await;
    let scaled = client.declare_subscriber("bridge/scaled/VAL").await.unwrap();
    let _bridge = TestNode::launch(&bridge_text).await;
    wait_until(&client, "bridge/scaled/VAL", 3.0).await;
    // Published as the node's state, marked found (the wire contract's `found`).
    let first = tokio::time::timeout(PATIENCE, scaled.recv_async()).await.expect("the record's value").unwrap();
    let marker = first.attachment().and_then(|a| zmotor_msgs::StateMarker::decode(&a.to_bytes()));
    assert!(marker.as_ref().is_some_and(|m| m.found), "not marked found: {marker:?}");
    tokio::time::sleep(Duration::from_millis(500)).await;
    val_stays(&client, &node, "m1", 2.0).await;
    confirmed_write(&client, &node.key("lead", Field::VAL), "0.5", PATIENCE).await.unwrap();
    wait_until(&client, &node.key("m1", Field::RBV), 1.0).await;
}

/// A source whose node restarts before its old token goes, when all a closed-loop DOL had of it
/// was its value read at connect (no post seen): the read told the session it came from, so the
/// new node's first post is found; the next one moves.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_dol_knows_a_restarted_source_by_the_session_its_read_came_from() {
    let text = with_fast_m1("\nOMSL = \"closed_loop\"\nDOL = \"motor/idle/RBV\"\n");
    let node = TestNode::launch(&text).await;
    let client = node.client().await;
    let mut idle = PlayedAxis::serve(node.client().await, "idle", 0.2).await;
    idle.come().await;
    // The node reads it when its token comes (then its answer travels back).
    let deadline = tokio::time::Instant::now() + PATIENCE;
    while idle.answered.load(std::sync::atomic::Ordering::SeqCst) == 0 {
        assert!(tokio::time::Instant::now() < deadline, "the node never read motor/idle/RBV");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    tokio::time::sleep(Duration::from_millis(200)).await;
    let mut restarted = PlayedAxis::serve(node.client().await, "idle", 0.4).await;
    restarted.post(0.4).await;
    restarted.come().await;
    drop(idle);
    tokio::time::sleep(Duration::from_millis(500)).await;
    val_stays(&client, &node, "m1", 0.0).await;
    restarted.post(0.6).await;
    wait_until(&client, &node.key("m1", Field::RBV), 0.6).await;
}
