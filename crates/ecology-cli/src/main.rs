//! The `ecology` command-line tool.

fn main() {}
