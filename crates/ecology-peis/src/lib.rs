//! The PEIS runtime of Ecology (DESIGN section 6): the [`Component`] trait for
//! functionality bodies, the [`Context`] they run in (params, inputs through
//! `mi-` meta-tuples, outputs, status), and [`run_host`], which runs one PEIS
//! with its init component on any [`ecology_tuples::TupleSpace`].

mod component;
mod host;

#[cfg(test)]
mod tests;

pub use component::{BoxFuture, Component, ComponentError, Context, Inputs};
pub use host::{ComponentSpec, HostError, HostOptions, announce_covers, run_host, run_host_with};
