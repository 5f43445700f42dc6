//! The task of one axis: the holds that went, autosave and shutdown. Each of these is an input
//! to the axis's inbox, like a write from the network (and like its input links' values, which
//! their senders deliver themselves: `LinkInbox`, and its ticks, which its clock delivers:
//! `Ticker`). The task sleeps between them: a poll does not wake it.

use crate::autosave::{SavedAxis, Saver};
use crate::axis_core::AxisInbox;
use crate::input::AxisInput;
use crate::tokens::{withdraw, TokenSlot};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc::UnboundedReceiver;
use tokio::sync::Notify;

/// How long a shutdown waits for moving axes to stop before saving anyway.
const STOP_GRACE: Duration = Duration::from_secs(5);
/// How often a stopping axis is looked at.
const STOP_CHECK: Duration = Duration::from_millis(10);

pub(crate) struct AxisTask {
    pub(crate) axis: Arc<AxisInbox>,
    pub(crate) name: String,
    /// Set when a field autosave keeps changed.
    pub(crate) unsaved: Arc<AtomicBool>,
    /// Wakes the task when `unsaved` is set.
    pub(crate) save_due: Arc<Notify>,
    /// Liveliness tokens of held motions that went.
    pub(crate) released: UnboundedReceiver<String>,
    pub(crate) saver: Option<Saver>,
    /// The axis's liveliness token, once declared.
    pub(crate) token: TokenSlot,
}

impl AxisTask {
    /// Serve until the node stops; then stop the motion, save and withdraw the liveliness token.
    pub(crate) async fn run(mut self, mut stopped: tokio::sync::watch::Receiver<bool>) {
        let mut stopping: Option<tokio::time::Instant> = None;
        let save_due = self.save_due.clone();
        loop {
            let next_save = self.saver.as_ref().and_then(Saver::due);
            tokio::select! {
                Some(token) = self.released.recv() => self.axis.deliver(AxisInput::HoldReleased(token)),
                _ = save_due.notified() => {}
                _ = tokio::time::sleep_until(next_save.unwrap_or_else(tokio::time::Instant::now)), if next_save.is_some() => {}
                _ = stopped.changed(), if stopping.is_none() => {
                    stopping = Some(tokio::time::Instant::now() + STOP_GRACE);
                    self.axis.deliver(AxisInput::StopMotion);
                }
                _ = tokio::time::sleep(STOP_CHECK), if stopping.is_some() => {}
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
