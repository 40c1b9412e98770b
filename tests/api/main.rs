//! Integration tests of `eyekey serve`: each test starts the real server on port 0 with its own data
//! directory and SQLite file, and talks HTTP to it with a real client.
//!
//! The tests that need a job to actually be solved (`whole_flow`, `fifty_jobs`, the restart of a
//! running job) run the real encoder; the others complete jobs with a hand-made bundle or drive the
//! queue directly.

mod helpers;

mod admission;
mod authorization;
mod connections;
mod console;
mod display_client;
mod displays;
mod documents;
mod encryption;
mod errors;
mod flow;
mod jobs;
mod openapi;
mod operations;
mod postgres;
mod profiles;
mod queue;
mod restart;
mod sealed;
mod tokens;
mod transport;
