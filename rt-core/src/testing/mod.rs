//! Test stand-ins (feature `testing`, never in the production build): [`toy`] holds a small
//! arm, scene, policy and lookahead that exercise the cycle and the twin worker without the
//! real twin. The adversarial sweep, which drives the production worker and cycle, is a
//! crate of its own (`rt-core/sweep`).

pub mod toy;
