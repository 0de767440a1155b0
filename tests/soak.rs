//! `soak` for a minute against the real binary: mixed load, the server killed with SIGKILL
//! and restarted twice, and still no job lost, no cancel undone, no wrong bytes and no answer
//! off the contract.

mod common;
use common::soak_kept_its_promises;

#[test]
fn a_minute_of_mixed_load_and_two_kills_loses_nothing() {
    let report = soak_kept_its_promises("sled", &["--restart-every", "20s"]);
    assert!(report["restarts"].as_u64() >= Some(2), "{report}");
}
