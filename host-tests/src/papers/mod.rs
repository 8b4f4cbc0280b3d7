//! The published papers' results as the papers state them: the reference models built from
//! their raw-unit coefficients ([`published`]). Their procedures are plans in
//! [`crate::data::plan`], their stages' twins in [`crate::twin::examples`], and `nanocal demo`
//! runs them end to end.

pub mod published;
