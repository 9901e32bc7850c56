//! The random initial values of a model as property-test inputs.

use crate::check::CheckedModel;
use crate::check::dag::{Dist as Draw, Node};
use crate::props::{Dist, Input};

/// The random parameters, then the scalar states whose initial value is a single draw
/// `uniform(lo, hi)` or `normal(mean, std)` with constant arguments, in
/// declaration order. These are what `hybsim test` samples and what
/// `--set name=value` pins. Family members (`x[2]`), vector states and
/// other random expressions (`2 * uniform(0, 1)`) keep their draw: they
/// cannot be pinned by name.
pub(crate) fn random_inputs(m: &CheckedModel) -> Vec<Input> {
    let states = m
        .fields
        .iter()
        .filter(|f| !f.generated && f.rows * f.cols == 1 && !f.name.contains('['))
        .filter_map(|f| {
            let Node::Rand(draw, a, b, _) = m.dag.node(*m.init.get(f.offset)?) else {
                return None;
            };
            let (a, b) = (m.dag.as_const(a)?, m.dag.as_const(b)?);
            let dist = match draw {
                Draw::Uniform => Dist::Uniform { lo: a, hi: b },
                Draw::Normal => Dist::Normal { mean: a, std: b },
                Draw::Bernoulli => return None,
            };
            dist.validate().ok()?;
            Some(Input::new(f.name.clone(), dist))
        });
    m.random_params.iter().cloned().chain(states).collect()
}
