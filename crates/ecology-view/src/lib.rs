//! Ecology's live view: what the ecology looks like now, from its tuples, its presence and the
//! executive's log ([`View`]); configurations drawn as SVG ([`Drawing`]), and the home, its rooms,
//! robots and things, from the `world` PEIS' tuples ([`Home`]); and the web page that
//! shows them as they change ([`serve`]), with nothing outside the binary.

pub mod home;
pub mod log_json;
mod server;
mod state;
pub mod svg;

pub use home::Home;
pub use server::{Hub, serve};
pub use state::View;
pub use svg::{Drawing, Edge, Mark, Node};
