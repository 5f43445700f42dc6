//! The task of one axis: its clock (periodic polls on tokio's timer, events such as the end of a
//! motion on the precise `Timer`), the holds that went, autosave and shutdown. Each of these is
//! an input to the axis's inbox, like a write from the network (and like its input links'
//! values, which their senders deliver themselves: `LinkInbox`).

use crate::autosave::{SavedAxis, Saver};
use crate::axis_core::AxisInbox;
use crate::input::AxisInput;
use crate::timer::Timer;
use crate::tokens::{withdraw, TokenSlot};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc::UnboundedReceiver;
use tokio::sync::Notify;

/// How long a shutdown waits for moving axes to stop before saving anyway.
const STOP_GRACE: Duration = Duration::from_secs(5);

pub(crate) struct AxisTask {
    pub(crate) axis: Arc<AxisInbox>,
    pub(crate) name: String,
    /// Wakes the task: an input handled elsewhere, or the precise timer.
    pub(crate) rearm: Arc<Notify>,
    /// Set when a field autosave keeps changed.
    pub(crate) unsaved: Arc<AtomicBool>,
    /// Set while a tick this task delivered waits for the thread handling the axis.
    pub(crate) tick_pending: Arc<AtomicBool>,
    /// Liveliness tokens of held motions that went.
    pub(crate) released: UnboundedReceiver<String>,
    pub(crate) saver: Option<Saver>,
    /// Wakes the task (through `rearm`) when the axis's next event comes.
    pub(crate) timer: Timer,
    /// The axis's liveliness token, once declared.
    pub(crate) token: TokenSlot,
    /// The origin of the axis's clock.
    pub(crate) clock: tokio::time::Instant,
}

impl AxisTask {
    /// Serve until the node stops; then stop the motion, save and withdraw the liveliness token.
    pub(crate) async fn run(mut self, mut stopped: tokio::sync::watch::Receiver<bool>) {
        let mut stopping: Option<tokio::time::Instant> = None;
        let mut scheduled = None;
        let rearm = self.rearm.clone();
        loop {
            // Registered before the deadlines are read: an input handled after this wakes the
            // task, one handled before is in what it reads.
            let woken = rearm.notified();
            tokio::pin!(woken);
            woken.as_mut().enable();
            // Polls keep tokio's millisecond timer; events (the end of a motion, DLY) also go to
            // the precise one, so they are reported when they happen. A Soft Channel axis may
            // have no deadline at all.
            let clock = self.clock;
            let (mut next, event) = self.axis.inspect(|core| {
                let at = |t: zmotor_core::Instant| clock + t.since_origin();
                (core.service.poll_timeout().map(at), core.service.event_timeout().map(at))
            });
            if self.tick_pending.load(Ordering::Acquire) {
                // Its handling wakes the task; until then the deadline read is the old one.
                next = None;
            }
            if event != scheduled {
                if let Some(at) = event {
                    self.timer.wake_at(at.into_std(), self.rearm.clone());
                }
                scheduled = event;
            }
            let other = [next, stopping, self.saver.as_ref().and_then(Saver::due)].into_iter().flatten().min();
            tokio::select! {
                Some(token) = self.released.recv() => self.axis.deliver(AxisInput::HoldReleased(token)),
                _ = &mut woken => {}
                _ = tokio::time::sleep_until(other.unwrap_or(clock)), if other.is_some() => {}
                _ = stopped.changed(), if stopping.is_none() => {
                    stopping = Some(tokio::time::Instant::now() + STOP_GRACE);
                    self.axis.deliver(AxisInput::StopMotion);
                }
            }
            // Whatever woke the task, the axis's own time may have come.
            if next.is_some_and(|at| tokio::time::Instant::now() >= at) {
                self.tick_pending.store(true, Ordering::Release);
                self.axis.deliver(AxisInput::Tick);
                scheduled = None;
            }
            self.autosave(false).await;
            let done = self.axis.inspect(|core| core.service.fields().dmov == 1);
            if stopping.is_some_and(|limit| done || tokio::time::Instant::now() >= limit) {
                break;
            }
        }
        if self.axis.inspect(|core| core.service.fields().dmov == 0) {
            tracing::warn!(axis = %self.name, "still moving {STOP_GRACE:?} after the stop; saving anyway");
        }
        self.autosave(true).await;
        withdraw(&self.token).await;
    }

    /// Note changes of saved fields, and write the file when due (or now, with `finally`).
    async fn autosave(&mut self, finally: bool) {
        let Some(saver) = &mut self.saver else { return };
        let now = tokio::time::Instant::now();
        if self.unsaved.swap(false, Ordering::AcqRel) {
            saver.changed(now);
        }
        if finally || saver.due().is_some_and(|due| now >= due) {
            let saved = self.axis.inspect(|core| SavedAxis::of(core.service.fields()));
            saver.flush(&self.name, saved).await;
        }
    }
}
