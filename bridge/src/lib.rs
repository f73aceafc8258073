//! `bridge` — everything Zenoh in koopbridge: key expressions, messages and their codec, the
//! services (trainer, model store, MPC, recorder), the lockstep/free-run orchestrator and a client.
