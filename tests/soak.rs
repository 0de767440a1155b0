//! `soak` for a minute against the real binary: mixed load, the server killed with SIGKILL
//! and restarted twice, and still no job lost, no cancel undone, no wrong bytes and no answer
//! off the contract.

mod common;
use common::cli;

#[test]
fn a_minute_of_mixed_load_and_two_kills_loses_nothing() {
    let dir = std::env::temp_dir().join(format!("occluder-cook-soak-{}", std::process::id()));
    let json = dir.with_extension("json");
    let (code, stdout, stderr) = cli(&[
        "soak",
        "--duration",
        "60s",
        "--restart-every",
        "20s",
        "--clients",
        "3",
        "--dir",
        dir.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
    ]);
    println!("{stdout}");
    assert_eq!(code, 0, "{stdout}{stderr}");
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert!(report["restarts"].as_u64() >= Some(2), "{report}");
    assert!(report["jobs_accepted"].as_u64() > Some(10), "{report}");
    assert_eq!(report["jobs_lost"], 0, "{report}");
    let ended: u64 = ["jobs_done", "jobs_failed", "jobs_cancelled"]
        .iter()
        .map(|field| report[field].as_u64().unwrap())
        .sum();
    assert_eq!(ended, report["jobs_accepted"].as_u64().unwrap(), "{report}");
    assert_eq!(report["cancels_undone"], 0, "{report}");
    assert_eq!(report["wrong_bytes"], 0, "{report}");
    assert_eq!(report["wrong_keys"], 0, "{report}");
    assert!(report["occluders_fetched"].as_u64() > Some(100), "{report}");
    assert_eq!(report["unexpected"], serde_json::json!({}), "{report}");
    for kind in [
        "new_mesh",
        "duplicate",
        "poll",
        "cancel",
        "cached_get",
        "malformed",
        "oversized",
        "unauthenticated",
    ] {
        assert!(
            report["requests"][kind].as_u64() > Some(0),
            "no {kind} requests: {report}"
        );
    }
    let minute = &report["minutes"][0];
    assert!(
        minute["cached_gets"].as_u64() > Some(0) && minute["peak_rss_mib"].as_f64() > Some(1.0),
        "{report}"
    );
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_file(&json);
}
