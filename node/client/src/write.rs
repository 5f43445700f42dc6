//! The one confirmed write every zmotor client sends (the command line, Channel Access, the
//! web page): to the axis's write key, with `?wait` and a hold when asked. It is sent at once,
//! so a client's writes reach the node in the order it made them, and its outcome is awaited
//! apart. The axis's liveliness token, watched from before the write, tells a node that vanished
//! before answering from an axis nobody serves.

use crate::Client;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};
use zenoh::bytes::Encoding;
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::Subscriber;
use zenoh::query::Reply;
use zenoh::sample::{Sample, SampleKind};
use zmotor_msgs::decode_cbor_value;
use zmotor_msgs::{Completion, Field, Hold, Refusal, Value};

/// How a write is sent.
#[derive(Clone, Debug, PartialEq)]
pub struct WriteOptions {
    /// Answered at the end of the motion the write starts (`?wait`, put-with-completion).
    pub wait: bool,
    /// The key of the liveliness token that holds what the write starts (the jog deadman).
    pub hold: Option<String>,
    /// How long the answer may take.
    pub patience: Duration,
}

impl WriteOptions {
    /// Answered at once, held by nothing, within `patience`.
    pub fn confirmed(patience: Duration) -> Self {
        Self { wait: false, hold: None, patience }
    }

    /// Answered at the end of the motion it starts, within `patience`.
    pub fn waiting(patience: Duration) -> Self {
        Self { wait: true, hold: None, patience }
    }

    /// The same, held by the liveliness token `token`.
    pub fn held_by(self, token: Option<String>) -> Self {
        Self { hold: token, ..self }
    }
}

/// How a confirmed write ended.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum WriteOutcome {
    /// Taken: the field's value now.
    Accepted(Value),
    /// Taken, and the motion it started is over (`?wait`).
    Completed(Completion),
    /// Refused: nothing changed but what the refusal's kind says (see `RefusalKind`).
    Refused(Refusal),
    /// The node serving the axis went away before it answered: the write's outcome is unknown.
    Vanished,
    /// Nothing answered.
    NoAnswer(NoAnswer),
}

/// Why a write got no answer at all.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum NoAnswer {
    /// No node serves the axis (its liveliness token was not seen).
    NotServed,
    /// The axis is served, but nothing answered: under access control, a request the rules deny
    /// gets no answer at all.
    Silent,
    /// The axis is served and the answer did not come within the write's patience.
    TimedOut,
}

impl std::fmt::Display for NoAnswer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            NoAnswer::NotServed => "no node serves the axis",
            NoAnswer::Silent => {
                "the axis is served but its node gave no answer (under access control, a request the rules \
                 deny gets no answer either)"
            }
            NoAnswer::TimedOut => "the axis is served but did not answer in time",
        })
    }
}

/// How long a write whose query ended unanswered waits to see the axis's token go: a node that
/// dies ends the query before its token is seen to go.
const VANISHING: Duration = Duration::from_secs(3);

/// A confirmed write on its way; `outcome` awaits the node's answer.
#[must_use = "a write's outcome says whether it was taken"]
pub struct SentWrite {
    replies: FifoChannelHandler<Reply>,
    token: Subscriber<FifoChannelHandler<Sample>>,
    wait: bool,
    sent: Instant,
    patience: Duration,
}

impl Client {
    /// Send `value` (text, as a user types it) to `axis`'s `field` as a confirmed write to its
    /// write key.
    pub async fn write(
        &self,
        axis: &str,
        field: Field,
        value: impl Into<String>,
        options: WriteOptions,
    ) -> Result<SentWrite, zenoh::Error> {
        let layout = self.layout();
        let token = self.session().liveliness().declare_subscriber(layout.axis(axis)).history(true).await?;
        let mut request = self
            .session()
            .get(layout.write_selector(axis, field, options.wait))
            .payload(value.into())
            .encoding(Encoding::TEXT_PLAIN)
            .timeout(options.patience);
        if let Some(hold) = &options.hold {
            request = request.attachment(Hold::new(hold).encode());
        }
        let replies = request.await?;
        Ok(SentWrite { replies, token, wait: options.wait, sent: Instant::now(), patience: options.patience })
    }
}

impl SentWrite {
    /// How the write ended.
    pub async fn outcome(self) -> WriteOutcome {
        // A token that goes and comes back (its node's link to a router flapped) is no vanished
        // node: the write's answer, if it comes, says how it ended.
        let (mut served, mut went, mut timed_out) = (false, false, false);
        loop {
            tokio::select! {
                reply = self.replies.recv_async() => match reply {
                    Ok(reply) if reply.result().is_err_and(crate::timed_out) => {
                        timed_out = true;
                        break;
                    }
                    Ok(reply) => return self.answered(reply),
                    Err(_) => break,
                },
                change = self.token.recv_async() => match change {
                    Ok(sample) if sample.kind() == SampleKind::Put => served = true,
                    Ok(_) => went = true,
                    Err(_) => {}
                },
            }
        }
        // The query ended unanswered: was the node there, and did it go?
        while let Ok(Some(sample)) = self.token.try_recv() {
            match sample.kind() {
                SampleKind::Put => served = true,
                SampleKind::Delete => went = true,
            }
        }
        if !served {
            return WriteOutcome::NoAnswer(NoAnswer::NotServed);
        }
        // Only a query that ended before its time may be a node that died (and whose token is
        // yet to be seen to go): one that ran its time (Zenoh's own timeout answer) says so at
        // once, not after `VANISHING`.
        let timed_out = timed_out || self.sent.elapsed() >= self.patience;
        if self.wait && (went || (!timed_out && self.vanishes().await)) {
            return WriteOutcome::Vanished;
        }
        if timed_out {
            WriteOutcome::NoAnswer(NoAnswer::TimedOut)
        } else {
            WriteOutcome::NoAnswer(NoAnswer::Silent)
        }
    }

    fn answered(&self, reply: Reply) -> WriteOutcome {
        match reply.into_result() {
            Ok(sample) => {
                let payload = sample.payload().to_bytes();
                let decoded = if self.wait {
                    ciborium::from_reader::<Completion, _>(&payload[..]).map(WriteOutcome::Completed).ok()
                } else {
                    decode_cbor_value(&payload).map(WriteOutcome::Accepted).ok()
                };
                decoded.unwrap_or_else(|| WriteOutcome::Accepted(Value::Text(String::from_utf8_lossy(&payload).into())))
            }
            Err(error) => {
                WriteOutcome::Refused(Refusal::from_wire(&error.encoding().to_string(), &error.payload().to_bytes()))
            }
        }
    }

    /// Whether the axis's token goes within `VANISHING`.
    async fn vanishes(&self) -> bool {
        let gone = async {
            while let Ok(sample) = self.token.recv_async().await {
                if sample.kind() == SampleKind::Delete {
                    return true;
                }
            }
            false
        };
        tokio::time::timeout(VANISHING, gone).await.unwrap_or(false)
    }
}

/// A value of a completion line: a double to 15 significant digits, so that the last bit of a
/// sum (7.0120000000000005) does not show; 10 stays 10.
fn tidy(value: &Value) -> String {
    match value {
        Value::Float(x) if x.is_finite() => {
            let rounded: f64 = format!("{x:.14e}").parse().unwrap_or(*x);
            rounded.to_string()
        }
        other => other.to_string(),
    }
}

impl std::fmt::Display for WriteOutcome {
    /// As the command line prints it: a value or the completion's `NAME=value` pairs, the
    /// refusal's words, or why nothing is known.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            WriteOutcome::Accepted(value) => write!(f, "{value}"),
            WriteOutcome::Completed(completion) => {
                // Every value of the completion, by name in order (DMOV, LVIO, ..., the written
                // field, reached), as the command line has always printed it; then what the
                // controller reported, a line each.
                let c = completion;
                let mut pairs: BTreeMap<&str, Value> = c.written.iter().map(|(n, v)| (n.as_str(), v.clone())).collect();
                pairs.extend([
                    ("RBV", Value::Float(c.rbv)),
                    ("DMOV", Value::Int(c.dmov)),
                    ("MISS", Value::Int(c.miss)),
                    ("LVIO", Value::Int(c.lvio)),
                    ("STAT", Value::Int(c.stat)),
                    ("SEVR", Value::Int(c.sevr)),
                    ("reached", Value::Int(c.reached)),
                ]);
                let line: Vec<String> = pairs.iter().map(|(name, value)| format!("{name}={}", tidy(value))).collect();
                f.write_str(&line.join(" "))?;
                c.err.iter().try_for_each(|message| write!(f, "\nERR: {message}"))
            }
            WriteOutcome::Refused(refusal) => write!(f, "{refusal}"),
            WriteOutcome::Vanished => {
                f.write_str("the node serving the axis vanished before answering: the write's outcome is unknown")
            }
            WriteOutcome::NoAnswer(why) => write!(f, "{why}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_completion_line_shows_doubles_without_the_last_bits_noise() {
        assert_eq!(tidy(&Value::Float(7.012_000_000_000_000_5)), "7.012");
        assert_eq!(tidy(&Value::Float(10.0)), "10");
        assert_eq!(tidy(&Value::Float(-1.25e-7)), "-0.000000125");
        assert_eq!(tidy(&Value::Int(3)), "3");
    }
}
