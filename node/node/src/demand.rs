//! Which fields some subscriber on the network wants, of any axis: one probe publisher per
//! field on `<prefix>/*/<FIELD>` whose matching status Zenoh keeps current. A field nobody
//! subscribes to, for any axis, is not published (the record posts monitors only to those who
//! asked); a subscriber of any axis's field gets that field from every axis, so no subscriber is
//! ever missed. (A matching listener per axis and field does not scale in Zenoh 1.10: every
//! subscriber declaration re-evaluates every listener.)

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use zenoh::sample::Locality;
use zenoh::Session;
use zmotor_msgs::{Field, KeyLayout};

pub(crate) struct FieldDemand {
    wanted: Vec<Arc<AtomicBool>>,
    _probes: Vec<zenoh::pubsub::Publisher<'static>>,
}

impl FieldDemand {
    pub(crate) async fn declare(session: &Session, layout: &KeyLayout) -> Result<Self, zenoh::Error> {
        let (mut wanted, mut probes) = (Vec::new(), Vec::new());
        for field in Field::all() {
            let probe =
                session.declare_publisher(layout.field("*", field)).allowed_destination(Locality::Remote).await?;
            let flag = Arc::new(AtomicBool::new(true));
            let listener = flag.clone();
            probe
                .matching_listener()
                .callback(move |status| listener.store(status.matching(), Ordering::Release))
                .background()
                .await?;
            wanted.push(flag);
            probes.push(probe);
        }
        Ok(Self { wanted, _probes: probes })
    }

    pub(crate) fn wanted(&self, field: Field) -> bool {
        self.wanted[field as usize].load(Ordering::Acquire)
    }
}
