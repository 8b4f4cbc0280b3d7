//! What a measurement is on the host: recordings in the shared CSV layout ([`recording`]), PI's
//! GCSArray data-recorder files imported as recordings ([`gcsarray`]), the published
//! procedures as plans ([`plan`]), dwell and step averages of a recording ([`dwell`]) and
//! λ_KMZ from two readings of the reference at the KMZ pose ([`kmz`]).

pub mod dwell;
pub mod gcsarray;
pub mod kmz;
pub mod plan;
pub mod recording;
