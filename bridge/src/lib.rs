//! zmotor-bridge: soft-channel wiring between keys, beside the engine on top of `msgs`: the
//! EPICS calc expression language (`Expression`) and the calcout-like links between keys
//! (`CalcLink`). Both are sans-IO: the node runs them.

mod calc;
mod link;

pub use calc::{input_name, CalcError, Expression, INPUTS, MAX_LENGTH, MAX_NESTING, TRANSFORM_FIELDS};
pub use link::{find_cycle, input_index, CalcLink, CalcLinkSpec, InputMode, InputSpec, LinkError, OutputOption};
