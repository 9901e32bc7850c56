//! Paper reproductions, one binary, a module per paper (or per part of one):
//! each checks a paper's claims through the real pipeline and keeps its
//! section of the repository's REPRODUCTION.md in sync.

mod intermittent_certificate;
mod intermittent_check;
mod intermittent_estimation;
mod intermittent_model;
mod intermittent_reproduction;
mod muehlebach;
mod perez_salesa;
mod util;
mod variance_trigger;
mod wu_ugrinovskii_allgower;
