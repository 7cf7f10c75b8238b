//! pabctl: the workstation side of port arbitration.
//!
//! Reads a network file, proves its rules consistent, compiles one table image per node and
//! simulates the whole network with `pab-core`, the code the boards run.

pub mod plot;
