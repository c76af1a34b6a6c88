//! Integration tests live beside this file; see `Cargo.toml`.
