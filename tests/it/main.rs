//! Integration tests, one binary, a module per area.

mod cli;
mod design;
mod design_backend;
mod design_check;
mod design_failure;
mod diagnostics;
mod engine;
mod features;
mod intermittent_certificate;
mod intermittent_check;
mod intermittent_estimation;
mod intermittent_model;
mod intermittent_reproduction;
mod lang;
mod models;
mod muehlebach;
mod perez_salesa;
mod props;
mod props_cli;
mod props_model;
mod props_params;
mod sinks;
mod util;
mod variance_props;
mod variance_trigger;
mod wu_ugrinovskii_allgower;
