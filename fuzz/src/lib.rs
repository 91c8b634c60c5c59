//! Shared code of the m6p-twin fuzz targets (`fuzz_targets/*.rs`) and of the seed
//! generator (`seeds/make_seeds.rs`).
//!
//! - [`enc`]: the inverse of `arbitrary`'s decoding, so seeds can be written as values.
//! - [`harness`]: the node-core harness (a node and its application driven by operations).
//! - [`nodes`]: the six node cores, with their structured ICD request generators.
//! - [`cfp_input`]: the CFP target's input.
//! - [`kiss_input`]: the KISS target's input layout (chunk sizes, then the stream).
//! - [`link_input`]: the outside link target's input (its configuration, then chunks).

#[macro_use]
pub mod macros;
pub mod cfp_input;
pub mod enc;
pub mod harness;
pub mod kiss_input;
pub mod link_input;
pub mod nodes;
