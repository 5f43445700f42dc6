//! The node's Zenoh entities for all its axes: one subscriber and one queryable per key space
//! (not per axis: Zenoh's cost per declaration grows with the declarations already there, and
//! thousands of axes would pay it squared). Their callbacks hand each sample or query to its
//! axis by name and never block: the node's own publications pass through them too.

use crate::input::{AxisInput, Written};
use crate::links::is_state;
use crate::refusal::refuse;
use crate::routes::{Routes, Space};
use crate::writer::Writer;
use std::sync::Arc;
use zenoh::key_expr::KeyExpr;
use zenoh::query::Query;
use zenoh::sample::{Locality, Sample};
use zenoh::Session;
use zmotor_msgs::{keys, Hold, KeyLayout, PayloadEncoding, RefusalKind};

/// Held for as long as the node serves.
pub(crate) struct Router {
    _writes: zenoh::pubsub::Subscriber<()>,
    _queries: zenoh::query::Queryable<()>,
    _confirmed_writes: zenoh::query::Queryable<()>,
    /// Gets of the readback bundles (`**` does not reach a chunk that starts with `@`).
    _readbacks: zenoh::query::Queryable<()>,
    _sim_writes: zenoh::pubsub::Subscriber<()>,
    _sim_queries: zenoh::query::Queryable<()>,
}

impl Router {
    /// Serve `routes`; `writer` reaches them from now on.
    pub(crate) async fn declare(
        session: &Session,
        layout: &KeyLayout,
        routes: Routes,
        writer: &Writer,
    ) -> Result<Self, zenoh::Error> {
        let routes = Arc::new(routes);
        writer.reach(&routes);
        let fields = Space::Fields(layout.clone());
        let (r1, s1) = (routes.clone(), fields.clone());
        let (r2, s2) = (routes.clone(), fields.clone());
        let (r5, s5) = (routes.clone(), fields);
        let (r6, l6) = (routes.clone(), layout.clone());
        let (r3, r4) = (routes.clone(), routes);
        // The node's own publications do not come back to it: what it writes to its own axes
        // goes through `Writer`.
        Ok(Self {
            _writes: session
                .declare_subscriber(layout.every_field())
                .allowed_origin(Locality::Remote)
                .callback(move |sample| {
                    if !is_state(&sample) {
                        route_sample(&r1, &s1, &sample, AxisInput::Write);
                    }
                })
                .await?,
            _queries: session
                .declare_queryable(layout.everything())
                .callback(move |q| route_query(&r2, &s2, q, AxisInput::Query))
                .await?,
            // `<prefix>/**` does not cover the `@write` chunk: write keys are served apart.
            _confirmed_writes: session
                .declare_queryable(layout.every_write())
                .callback(move |q| route_query(&r5, &s5, q, AxisInput::Query))
                .await?,
            _readbacks: session
                .declare_queryable(layout.readback("*"))
                .callback(move |q| route_readback(&r6, &l6, &q))
                .await?,
            _sim_writes: session
                .declare_subscriber(keys::sim_key("*", "*"))
                .allowed_origin(Locality::Remote)
                .callback(move |sample| {
                    if !is_state(&sample) {
                        route_sample(&r3, &Space::Sim, &sample, AxisInput::SimWrite);
                    }
                })
                .await?,
            _sim_queries: session
                .declare_queryable(keys::sim_key("*", "**"))
                .callback(move |q| route_query(&r4, &Space::Sim, q, AxisInput::SimQuery))
                .await?,
        })
    }
}

/// A sample goes to the axis its key names, if it is one of ours.
fn route_sample(routes: &Routes, space: &Space, sample: &Sample, wrap: fn(Written) -> AxisInput) {
    if sample.key_expr().as_str().contains(['*', '$']) {
        tracing::warn!(key = %sample.key_expr(), "a put to a key with wildcards is not a write; ignored");
        return;
    }
    if let Some((handle, name)) = space.target(routes, sample.key_expr().as_str()) {
        let encoding = PayloadEncoding::from_mime(&sample.encoding().to_string());
        let hold = sample.attachment().and_then(|a| Hold::decode(&a.to_bytes()));
        handle.deliver(wrap(Written { name, payload: sample.payload().to_bytes().into_owned(), encoding, hold }));
    }
}

/// A get of readback bundles goes to every axis of ours whose bundle it names.
fn route_readback(routes: &Routes, layout: &KeyLayout, query: &Query) {
    for (axis, handle) in routes.iter() {
        if KeyExpr::try_from(layout.readback(axis)).is_ok_and(|key| query.key_expr().intersects(&key)) {
            handle.deliver(AxisInput::Query(query.clone()));
        }
    }
}

/// A query goes to every axis of ours it can concern (one, or all for a wildcard).
fn route_query(routes: &Routes, space: &Space, query: Query, wrap: fn(Query) -> AxisInput) {
    if query.payload().is_some() && query.key_expr().as_str().contains(['*', '$']) {
        // Answering with the fields' values would look like success, and writing every match
        // is not what a write means: refused, naming the key.
        let message = format!("{}: a write names one field of one axis; this key has wildcards", query.key_expr());
        refuse(&query, RefusalKind::Wildcard, message);
        return;
    }
    let chunk = space.axis_chunk(query.key_expr().as_str()).unwrap_or("");
    if !chunk.is_empty() && !chunk.contains(['*', '$']) {
        if let Some(handle) = routes.get(chunk) {
            handle.deliver(wrap(query));
        }
        return;
    }
    for (axis, handle) in routes.iter() {
        let Ok(all) = KeyExpr::try_from(space.everything_of(axis)) else { continue };
        if query.key_expr().intersects(&all) {
            handle.deliver(wrap(query.clone()));
        }
    }
}
