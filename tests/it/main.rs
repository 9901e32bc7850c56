//! Integration tests, one binary, a module per area.

mod sinks;
mod util;
