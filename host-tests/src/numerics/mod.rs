//! The numerics every other room builds on: dense least squares by Householder QR
//! ([`linalg`]), distribution functions ([`stats`]), stepwise regression with MATLAB
//! `stepwisefit` semantics ([`stepwise`]) and what a fit knows about itself ([`uncertainty`]).
//! Nothing here knows about stages, recordings or models.

pub mod linalg;
pub mod stats;
pub mod stepwise;
pub mod uncertainty;
