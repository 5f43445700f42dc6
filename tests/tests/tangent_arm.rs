//! The seed manual's tangent arm (launch/tangent-arm.toml) over real Zenoh sessions: a soft
//! rotary motor in degrees drives a simulated linear stage in mm through two calc links.

use std::time::Duration;
use zmotor_msgs::{Field, Value};
use zmotor_tests::*;

/// The launch file with a fast linear stage (577 mm take 23 s at the manual's 25 mm/s).
fn tangent_arm(extra_rotary_fields: &str) -> String {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../launch/tangent-arm.toml")).unwrap();
    text.replace("VELO = 25.0", "VELO = 2500.0")
        .replace("EGU = \"deg.\"", &format!("EGU = \"deg.\"\n{extra_rotary_fields}"))
}

fn near(v: &Value, target: f64, tolerance: f64) -> bool {
    v.as_f64().is_some_and(|x| (x - target).abs() <= tolerance)
}

/// Wait until the rotary motor has its first readback (its target is set from it).
async fn ready(node: &TestNode, client: &zenoh::Session) {
    for _ in 0..100 {
        if get_value(client, &node.key("rotary", Field::RRBV)).await == Value::Int(0)
            && get_value(client, &node.key("rotary", Field::DMOV)).await == Value::Int(1)
        {
            tokio::time::sleep(Duration::from_millis(100)).await;
            return;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    panic!("the rotary motor never got its readback");
}

async fn wait_until(client: &zenoh::Session, key: &str, accept: impl Fn(&Value) -> bool) -> Value {
    for _ in 0..200 {
        let v = get_value(client, key).await;
        if accept(&v) {
            return v;
        }
        tokio::time::sleep(Duration::from_millis(25)).await;
    }
    panic!("{key} never reached the expected value");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_rotary_move_drives_the_linear_stage_and_reads_back() {
    let node = TestNode::launch(&tangent_arm("")).await;
    let client = node.client().await;
    ready(&node, &client).await;
    let mut rotary = Recorder::new(&node, &client, "motor/rotary/DMOV").await;
    let mut linear = Recorder::new(&node, &client, "motor/linear/DMOV").await;
    put_text(&client, &node.key("rotary", Field::VAL), "30").await;
    linear.wait_for("DMOV", |v| *v == int(1)).await;
    rotary.wait_for("DMOV", |v| *v == int(1)).await;
    rotary.drain_for(Duration::from_millis(300)).await;
    linear.drain_for(Duration::from_millis(10)).await;
    assert_eq!(rotary.values("DMOV"), vec![int(0), int(1)], "the rotary is done once, when the linear stage is");
    assert_eq!(linear.values("DMOV"), vec![int(0), int(1)]);
    let dval = get_value(&client, &node.key("linear", Field::DVAL)).await;
    assert!(near(&dval, 577.35, 0.01), "linear DVAL {dval:?}");
    wait_until(&client, &node.key("rotary", Field::RBV), |v| near(v, 30.0, 0.002)).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stop_on_the_rotary_stops_the_linear_stage() {
    let node = TestNode::launch(&tangent_arm("").replace("VELO = 2500.0", "VELO = 100.0")).await;
    let client = node.client().await;
    ready(&node, &client).await;
    let mut linear = Recorder::new(&node, &client, "motor/linear/*").await;
    put_text(&client, &node.key("rotary", Field::VAL), "30").await;
    linear.wait_for("RBV", |v| v.as_f64().unwrap() > 5.0).await;
    put_text(&client, &node.key("rotary", Field::STOP), "1").await;
    linear.wait_for("DMOV", |v| *v == int(1)).await;
    let stopped_at = get_value(&client, &node.key("linear", Field::RBV)).await.as_f64().unwrap();
    assert!(stopped_at > 5.0 && stopped_at < 100.0, "linear stopped at {stopped_at}");
    // The rotary's target follows the readback of where the arm stopped.
    let rotary_rbv = wait_until(&client, &node.key("rotary", Field::DMOV), |v| *v == int(1)).await;
    assert_eq!(rotary_rbv, int(1));
    let expected = (stopped_at / 1000.0).atan() * 57.296;
    wait_until(&client, &node.key("rotary", Field::RBV), |v| near(v, expected, 0.002)).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn moving_the_linear_stage_directly_resynchronises_the_rotary_unless_locked() {
    for (lock, follows) in [("NO", true), ("YES", false)] {
        let node = TestNode::launch(&tangent_arm(&format!("LOCK = \"{lock}\""))).await;
        let client = node.client().await;
        ready(&node, &client).await;
        let expected = (100.0f64 / 1000.0).atan() * 57.296;
        let _ = confirmed_write(&client, "motor/linear/VAL?wait", "100", PATIENCE).await.unwrap();
        wait_until(&client, &node.key("rotary", Field::RBV), |v| near(v, expected, 0.002)).await;
        tokio::time::sleep(Duration::from_millis(200)).await;
        let val = get_value(&client, &node.key("rotary", Field::VAL)).await;
        assert_eq!(near(&val, expected, 0.002), follows, "LOCK {lock}: rotary VAL {val:?}");
        assert_eq!(get_value(&client, &node.key("rotary", Field::DMOV)).await, int(1));
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_rotary_limits_refuse_fifty_degrees() {
    let node = TestNode::launch(&tangent_arm("")).await;
    let client = node.client().await;
    ready(&node, &client).await;
    let mut linear = Recorder::new(&node, &client, "motor/linear/DVAL").await;
    let err = confirmed_write(&client, &node.key("rotary", Field::VAL), "50", PATIENCE).await.unwrap_err();
    assert!(err.starts_with("VAL: limit violation"), "{err}");
    assert_eq!(get_value(&client, &node.key("rotary", Field::LVIO)).await, int(1));
    linear.drain_for(Duration::from_millis(300)).await;
    assert!(linear.values("DVAL").is_empty(), "nothing was sent to the linear stage");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn restarting_the_bridge_moves_nothing() {
    // The axes in one node, the calc links in a bridge of their own connected to it.
    let text = tangent_arm("");
    let (axes, calcs) = text.split_once("[[calc]]").unwrap();
    let bridge_text =
        |endpoint: &str| format!("[zenoh]\nmode = \"peer\"\nlisten = []\nconnect = [\"{endpoint}\"]\n[[calc]]{calcs}");
    let node = TestNode::launch(axes).await;
    let client = node.client().await;
    let bridge = TestNode::launch(&bridge_text(&node.endpoint)).await;
    ready(&node, &client).await;
    let _ = confirmed_write(&client, "motor/rotary/VAL?wait", "10", PATIENCE).await.unwrap();
    wait_until(&client, &node.key("rotary", Field::RBV), |v| near(v, 10.0, 0.002)).await;
    let mut watch = Recorder::new(&node, &client, "motor/*/*").await;
    drop(bridge);
    watch.drain_for(Duration::from_millis(300)).await;
    let restarted = TestNode::launch(&bridge_text(&node.endpoint)).await;
    watch.drain_for(Duration::from_millis(800)).await;
    let moved: Vec<_> = watch.seen.iter().filter(|s| s.key.ends_with("/DMOV") || s.key.ends_with("/DVAL")).collect();
    assert!(moved.is_empty(), "a restarted bridge moved something: {moved:?}");
    assert!(near(&get_value(&client, &node.key("rotary", Field::RBV)).await, 10.0, 0.002));
    assert!(near(&get_value(&client, &node.key("rotary", Field::VAL)).await, 10.0, 0.002));
    // And the restarted bridge works.
    let _ = confirmed_write(&client, "motor/rotary/VAL?wait", "20", PATIENCE).await.unwrap();
    wait_until(&client, &node.key("linear", Field::DVAL), |v| near(v, (20.0f64 / 57.296).tan() * 1000.0, 0.01)).await;
    drop(restarted);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_completion_wait_on_the_rotary_right_after_a_linear_move_waits_for_the_rotary_move() {
    let node = TestNode::launch(&tangent_arm("")).await;
    let client = node.client().await;
    ready(&node, &client).await;
    let _ = confirmed_write(&client, "motor/linear/VAL?wait", "100", PATIENCE).await.unwrap();
    // At once, while the rotary is still following that move (its "done" settles for 50 ms):
    // the answer must come when the rotary's own move has ended, not with the end of the last.
    let reply = confirmed_write(&client, "motor/rotary/VAL?wait", "20", PATIENCE).await.unwrap();
    let outcome: std::collections::BTreeMap<String, Value> = ciborium::from_reader(&reply[..]).unwrap();
    assert_eq!(outcome["DMOV"], int(1), "{outcome:?}");
    let linear = get_value(&client, &node.key("linear", Field::RBV)).await;
    assert!(near(&linear, 363.97, 0.01), "TAN(20°)·1000 mm when the rotary is done, got {linear:?}");
}
