//! The liveliness tokens of a node's axes (`<prefix>/<axis>`), declared in order by a task of
//! their own once the axes already answer (Zenoh's cost per token grows with the tokens already
//! declared); each axis withdraws its own at shutdown.

use std::sync::{Arc, Mutex};
use zenoh::liveliness::LivelinessToken;
use zenoh::Session;
use zmotor_msgs::KeyLayout;

/// Where an axis's liveliness token is kept once declared.
pub(crate) type TokenSlot = Arc<Mutex<Option<LivelinessToken>>>;

/// The tokens to declare, with the slot of each.
#[derive(Default)]
pub(crate) struct Tokens(Vec<(String, TokenSlot)>);

impl Tokens {
    /// The slot `axis`'s token will be kept in.
    pub(crate) fn slot(&mut self, axis: &str) -> TokenSlot {
        let slot = TokenSlot::default();
        self.0.push((axis.to_string(), slot.clone()));
        slot
    }

    /// Declare them all, in order, unless the node stops first.
    pub(crate) fn declare_in_background(
        self,
        session: &Session,
        layout: &KeyLayout,
        stopped: tokio::sync::watch::Receiver<bool>,
    ) {
        let (session, layout) = (session.clone(), layout.clone());
        tokio::spawn(async move {
            for (axis, slot) in self.0 {
                if *stopped.borrow() {
                    return;
                }
                match session.liveliness().declare_token(layout.axis(&axis)).await {
                    Ok(token) => *slot.lock().unwrap_or_else(|e| e.into_inner()) = Some(token),
                    Err(e) => tracing::error!(axis, "cannot declare the liveliness token: {e}"),
                }
            }
        });
    }
}

/// Withdraw the token in `slot`, if it was declared.
pub(crate) async fn withdraw(slot: &TokenSlot) {
    let token = slot.lock().unwrap_or_else(|e| e.into_inner()).take();
    if let Some(token) = token {
        let _ = token.undeclare().await;
    }
}
