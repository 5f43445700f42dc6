//! The floor beside every figure: Zenoh alone, in processes of this program with no zmotor
//! code on the measured path. `zmotor-bench floor echo` answers pings as Zenoh's z_pong does
//! (from the subscriber's callback, through a declared publisher) and gets of one value;
//! `floor publish` publishes what as many moving axes publish, at the same rate; `floor tokens`
//! declares as many axes' liveliness tokens; `floor get` is a one-shot client, as a stock
//! tool's `get` is.

use crate::Error;
use std::time::Duration;
use zenoh::bytes::Encoding;
use zenoh::qos::CongestionControl;
use zenoh::{Session, Wait};
use zmotor_core::{AxisEvent, AxisPlan, DriverPlan, Instant, JogHold, PollRates, SimConfig};
use zmotor_deploy::ZenohConfig;
use zmotor_msgs::{encode_cbor, Field, Fields, KeyLayout, StateMarker, Value};

/// The echo's keys.
pub(crate) const PING: &str = "bench/ping";
pub(crate) const PONG: &str = "bench/pong";
/// The key `floor echo` answers gets of.
pub(crate) const VALUE: &str = "bench/value";
/// The key `floor publish --keys-new-at-go` waits for.
pub(crate) const GO: &str = "bench/go";

/// What a floor process does.
#[derive(clap::Subcommand, Clone, Debug)]
pub(crate) enum Floor {
    /// Answer pings and gets, listening on ENDPOINT.
    Echo {
        #[arg(long)]
        listen: String,
    },
    /// Publish what AXES moving axes publish, RATE polls a second, listening on ENDPOINT.
    Publish {
        #[arg(long)]
        listen: String,
        #[arg(long)]
        axes: usize,
        #[arg(long)]
        rate: f64,
        /// Declare the axes' liveliness tokens as a node does, then publish nothing until a
        /// sample on `bench/go`; then make each key new as a node's first moves do (a put
        /// without publisher on each field a move posts once, a publisher declared for each
        /// readback).
        #[arg(long)]
        keys_new_at_go: bool,
    },
    /// Declare the liveliness tokens of AXES axes, listening on ENDPOINT, and keep them.
    Tokens {
        #[arg(long)]
        listen: String,
        #[arg(long)]
        axes: usize,
    },
    /// One get of `bench/value` from ENDPOINT, then exit (a stock client's one-shot get).
    Get {
        #[arg(long)]
        connect: String,
    },
}

/// Run a floor process until it is killed (or, for `get`, until it has its answer).
pub(crate) async fn run(floor: Floor) -> Result<(), Error> {
    match floor {
        Floor::Echo { listen } => {
            let session = listening(&listen).await?;
            let pong = session.declare_publisher(PONG).congestion_control(CongestionControl::Block).await?;
            let _echo = session
                .declare_subscriber(PING)
                .callback(move |sample| {
                    let _ = pong.put(sample.payload().clone()).wait();
                })
                .await?;
            let _value = session
                .declare_queryable(VALUE)
                .callback(|query| {
                    let reply = query.reply(VALUE, encode_cbor(&Value::Float(1.0)));
                    let _ = reply.encoding(Encoding::APPLICATION_CBOR).wait();
                })
                .await?;
            std::future::pending::<()>().await;
            Ok(())
        }
        Floor::Publish { listen, axes, rate, keys_new_at_go } => {
            let session = listening(&listen).await?;
            if !keys_new_at_go {
                return publish_like_moving_axes(&session, Keys::Ahead(axes), rate).await;
            }
            // Under the axes' liveliness tokens, as a node's keys are: each new key's match
            // walks every axis then (part 18 of BENCHMARKS.md).
            let _tokens = declare_tokens(&session, axes).await?;
            let (went, mut go) = tokio::sync::mpsc::channel(1);
            let _go = session
                .declare_subscriber(GO)
                .callback(move |_| {
                    let _ = went.try_send(());
                })
                .await?;
            go.recv().await.ok_or("the go subscriber ended")?;
            publish_like_moving_axes(&session, Keys::NewAtGo(axes), rate).await
        }
        Floor::Tokens { listen, axes } => {
            let session = listening(&listen).await?;
            let _tokens = declare_tokens(&session, axes).await?;
            std::future::pending::<()>().await;
            Ok(())
        }
        Floor::Get { connect } => {
            let session = zmotor_client::open(&ZenohConfig::client(&connect)).await?;
            let replies = session.get(VALUE).timeout(Duration::from_secs(5)).await?;
            replies.recv_async().await?.result().map_err(|_| "the floor's value was not answered")?;
            session.close().await?;
            Ok(())
        }
    }
}

/// The liveliness tokens of `n` bench axes, as a node declares them.
async fn declare_tokens(session: &Session, n: usize) -> Result<Vec<zenoh::liveliness::LivelinessToken>, Error> {
    let layout = KeyLayout::default();
    let mut tokens = Vec::with_capacity(n);
    for i in 0..n {
        tokens.push(session.liveliness().declare_token(layout.axis(&crate::axes::bench_axis(i))).await?);
    }
    Ok(tokens)
}

async fn listening(endpoint: &str) -> Result<Session, Error> {
    let config = ZenohConfig { listen: vec![endpoint.to_string()], ..ZenohConfig::default() };
    Ok(zmotor_client::open(&config).await?)
}

/// The fields a moving axis posts at one readback poll (RBV, DRBV, RRBV, RMP, DIFF, RDIF), as
/// the engine says: a bench axis half a second into a long move, at its next poll.
pub(crate) fn fields_posted_per_poll() -> Vec<Field> {
    a_long_moves_posts().1
}

/// The fields a bench axis's long move posts in its first half second other than at every poll
/// (VAL, DMOV, MOVN, MSTA, ... once or a few times), each once, as the engine says.
fn fields_posted_at_a_moves_start() -> Vec<Field> {
    let (all, per_poll) = a_long_moves_posts();
    all.into_iter().filter(|f| !per_poll.contains(f)).collect()
}

/// What a bench axis's long move posts: every field in its first half second, each once, in the
/// order first posted; and the fields of its next poll.
fn a_long_moves_posts() -> (Vec<Field>, Vec<Field>) {
    let start = Instant::ZERO;
    let plan = AxisPlan {
        name: "b0".into(),
        fields: Fields { mres: 0.001, velo: 10.0, accl: 0.1, ..Fields::default() },
        driver: DriverPlan::Sim(SimConfig::default()),
        rates: PollRates { moving: Duration::from_millis(10), idle: Duration::from_secs(1) },
        jog_hold: JogHold::Optional,
    };
    let posted = |event| if let AxisEvent::Post(field, _) = event { Some(field) } else { None };
    let mut axis = plan.build(start, None);
    axis.write(start, Field::VAL, &Value::Float(1000.0)).expect("a bench move is accepted");
    let mut all = Vec::new();
    while axis.now() < start + Duration::from_millis(500) {
        for field in axis.drain_events().filter_map(posted) {
            if !all.contains(&field) {
                all.push(field);
            }
        }
        let t = axis.poll_timeout().expect("a simulated axis is polled");
        axis.handle_timeout(t);
    }
    (all, axis.drain_events().filter_map(posted).collect())
}

/// The floor's axes, and when their keys are made.
enum Keys {
    /// Their readbacks' publishers are declared at once (before any subscriber comes).
    Ahead(usize),
    /// Their keys are new at the first poll.
    NewAtGo(usize),
}

fn declare_readbacks(session: &Session, n: usize) -> Result<Vec<zenoh::pubsub::Publisher<'static>>, Error> {
    let (layout, fields) = (KeyLayout::default(), fields_posted_per_poll());
    let keys = (0..n).flat_map(|i| fields.iter().map(move |&field| (i, field)));
    keys.map(|(i, field)| {
        let key = layout.field(&crate::axes::bench_axis(i), field);
        session.declare_publisher(key).encoding(Encoding::APPLICATION_CBOR).wait()
    })
    .collect()
}

/// Zenoh alone doing the publishing of moving axes, `rate` times a second on a thread of its
/// own, on a fixed cadence (a precise sleep, as the node's tick workers; tokio's timer rounds to
/// the millisecond): each field of `fields_posted_per_poll` through a declared publisher, a CBOR
/// number with a state marker and a timestamp, as the node sends it (one stamp for the fields
/// of one axis's poll). Keys new at the first poll cost what a node's first moves cost them:
/// a put without publisher on each field a move posts once, then the readbacks' declarations.
async fn publish_like_moving_axes(session: &Session, keys: Keys, rate: f64) -> Result<(), Error> {
    let fields = fields_posted_per_poll();
    let period = Duration::from_secs_f64(1.0 / rate);
    let session = session.clone();
    let polls = tokio::task::spawn_blocking(move || -> Result<(), Error> {
        let start = std::time::Instant::now();
        let mut seq = 0;
        let mut marked = |stamp| {
            seq += 1;
            (encode_cbor(&Value::Float(seq as f64 * 1e-3)), StateMarker::new(seq, 0, 0).encode(), stamp)
        };
        let publishers = match keys {
            Keys::Ahead(n) => declare_readbacks(&session, n)?,
            Keys::NewAtGo(n) => {
                let (layout, once) = (KeyLayout::default(), fields_posted_at_a_moves_start());
                for i in 0..n {
                    let stamp = session.new_timestamp();
                    for &field in &once {
                        let (value, marker, stamp) = marked(stamp);
                        let put = session.put(layout.field(&crate::axes::bench_axis(i), field), value);
                        put.encoding(Encoding::APPLICATION_CBOR).attachment(marker).timestamp(stamp).wait()?;
                    }
                }
                declare_readbacks(&session, n)?
            }
        };
        for poll in 1u32.. {
            for axis in publishers.chunks(fields.len()) {
                let stamp = session.new_timestamp();
                for publisher in axis {
                    let (value, marker, stamp) = marked(stamp);
                    publisher.put(value).attachment(marker).timestamp(stamp).wait()?;
                }
            }
            if let Some(wait) = (start + period * poll).checked_duration_since(std::time::Instant::now()) {
                std::thread::sleep(wait);
            }
        }
        Ok(())
    });
    polls.await?
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_moving_axis_posts_its_six_readback_fields_per_poll() {
        let mut fields = fields_posted_per_poll();
        fields.sort_by_key(|f| f.name());
        assert_eq!(fields, [Field::DIFF, Field::DRBV, Field::RBV, Field::RDIF, Field::RMP, Field::RRBV]);
    }

    #[test]
    fn a_moves_start_posts_its_drive_and_status_fields_each_once_and_no_readback() {
        let once = fields_posted_at_a_moves_start();
        for field in [Field::VAL, Field::DVAL, Field::RVAL, Field::DMOV, Field::MOVN, Field::MSTA] {
            assert!(once.contains(&field), "{field} missing from {once:?}");
        }
        assert!(fields_posted_per_poll().iter().all(|f| !once.contains(f)), "{once:?}");
        assert!(once.iter().enumerate().all(|(i, f)| !once[..i].contains(f)), "each once: {once:?}");
    }
}
