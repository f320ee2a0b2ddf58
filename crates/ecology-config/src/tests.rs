//! Tests of the configuration planner.
