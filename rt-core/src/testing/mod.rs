//! Test stand-ins (feature `testing`, never in the production build): [`toy`] holds a small
//! arm, scene, policy and lookahead that exercise the cycle and the twin worker without the
//! real twin.

pub mod oracle;
pub mod sweep;
pub mod toy;
