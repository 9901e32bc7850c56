//! Integration tests, one binary, a module per area.

mod props;
mod sinks;
mod util;
