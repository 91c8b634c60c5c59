//! What a scenario means, one domain slice a module: each slice's check of its tables,
//! its compilation into the run's options, its expectation kinds, and the fault kinds
//! ([`faults`]); their registries ([`validate`], [`expectation_kinds`], the fault registry in
//! [`faults`]) and the whole compilation ([`plan`]).
//!
//! Slices: [`adcs`] (the FC), [`sessions`] (the PC and payloads), [`eps`], [`comm`] (the
//! radio and passes), [`commands`] (the ground's requests), [`outside`] (links to outside
//! programs), [`clock`], [`params`], [`rules`], [`invariants`], and the expectation kinds
//! [`can`], [`counters`], [`fields`], [`latency`].

pub mod adcs;
pub mod can;
pub mod clock;
pub mod comm;
pub mod commands;
pub mod counters;
pub mod eps;
pub mod expectation_kinds;
pub mod expectations;
pub mod faults;
pub mod fields;
pub mod invariants;
pub mod latency;
pub mod outside;
pub mod params;
pub mod plan;
pub mod rules;
pub mod sessions;
pub mod validate;
