//! The tuple space over Eclipse Zenoh.
