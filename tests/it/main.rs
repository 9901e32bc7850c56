//! Integration tests, one binary, a module per area.

mod lang;
mod props;
mod sinks;
mod util;
