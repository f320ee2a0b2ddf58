//! Tests of the domain language.
