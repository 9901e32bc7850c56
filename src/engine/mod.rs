//! The hybrid simulation engine. It knows nothing of the model language: it
//! runs any [`HybridSystem`].

pub mod system;

pub use system::{FlowStructure, GuardKind, HybridSystem, JumpRule, SimRng};
