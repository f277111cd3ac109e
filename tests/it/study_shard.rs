//! Sharding a study (`spinedrr study --shard I/N`, `--assemble`): every unit in exactly one shard for any
//! config and N = 1…16; shards run in any order and assembled give the unsharded run's tables byte for
//! byte; `--assemble` refuses while units are missing; a Slurm array task's environment selects the shard.

use std::collections::BTreeSet;
use std::path::Path;

use proptest::prelude::*;
use spinedrr::study::StudyConfig;
use spinedrr::study::config::{Experiment, RegistrationMethod};
use spinedrr::study::shard::{Shard, assign, units_of};
use spinedrr::study::units::enumerate_units;

use crate::common::{Spinedrr, csv_tables};

/// A config from the generated choices: phantom levels, segment, grid sizes, experiments, trials.
fn config(
    levels: usize,
    segment: bool,
    df: usize,
    piercing: usize,
    exps: u8,
    trials: usize,
    per_unit: usize,
) -> StudyConfig {
    let mut c = StudyConfig::quick();
    c.anatomy.levels = ["L1", "L2", "L3", "L4", "L5"][..levels]
        .iter()
        .map(|s| s.to_string())
        .collect();
    c.anatomy.segment = segment;
    c.perturbations.df_px = (1..=df).map(|i| 50.0 * i as f64).collect();
    c.perturbations.piercing_px = (0..piercing).map(|i| 10.0 * i as f64).collect();
    c.experiments = Experiment::ALL
        .iter()
        .enumerate()
        .filter(|(i, _)| exps & (1 << i) != 0)
        .map(|(_, e)| *e)
        .collect();
    c.registration.methods = vec![RegistrationMethod::Kabsch, RegistrationMethod::DirectAp];
    c.registration.trials = trials;
    c.registration.trials_per_unit = per_unit;
    c
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 32, ..ProptestConfig::default() })]

    /// The shards' unit lists partition the study's units: each unit in exactly one shard, for every
    /// N = 1…16, and the assignment is the same when computed again (every process computes its own).
    #[test]
    fn every_unit_is_in_exactly_one_shard(
        levels in 1usize..=5,
        segment in any::<bool>(),
        df in 1usize..=5,
        piercing in 1usize..=4,
        exps in 1u8..8,
        trials in 1usize..=12,
        per_unit in 1usize..=5,
    ) {
        let cfg = config(levels, segment, df, piercing, exps, trials, per_unit);
        let units = enumerate_units(&cfg).unwrap();
        let ids: std::collections::BTreeMap<String, usize> =
            units.iter().enumerate().map(|(i, u)| (u.id(), i)).collect();
        prop_assert_eq!(ids.len(), units.len());
        for n in 1..=16 {
            let a = assign(&cfg, &units, n);
            prop_assert_eq!(&a, &assign(&cfg, &units, n));
            let mut seen: Vec<usize> = vec![0; units.len()];
            for i in 0..n {
                for u in units_of(&cfg, &units, Shard::new(i, n).unwrap()) {
                    seen[ids[&u.id()]] += 1;
                }
            }
            prop_assert!(seen.iter().all(|&c| c == 1), "N = {}: {:?}", n, seen);
            prop_assert!(a.iter().all(|&s| s < n));
        }
    }
}

fn study(args: &[&str], out: &Path) -> (bool, String) {
    Spinedrr::new()
        .args(["study", "--quick", "--threads", "2"])
        .args(args)
        .arg("--out")
        .arg(out)
        .outcome()
}

/// Shards 2, 0, 3, 1 of 4 into one folder, then `--assemble`: the tables are byte-identical to one
/// unsharded run; before the last shard, `--assemble` fails naming the missing units.
#[test]
fn shards_in_any_order_assemble_to_the_unsharded_tables() {
    let dir = tempfile::tempdir().unwrap();
    let (whole, sharded) = (dir.path().join("whole"), dir.path().join("sharded"));
    let (ok, err) = study(&[], &whole);
    assert!(ok, "{err}");
    let cfg = StudyConfig::quick();
    let units = enumerate_units(&cfg).unwrap();
    for i in [2, 0, 3] {
        let (ok, err) = study(&["--shard", &format!("{i}/4")], &sharded);
        assert!(ok, "shard {i}: {err}");
        assert!(
            !sharded.join("tables").join("projection.csv").exists(),
            "a shard must not write tables"
        );
    }
    let missing = units_of(&cfg, &units, Shard::new(1, 4).unwrap());
    assert!(!missing.is_empty());
    let (ok, err) = study(&["--assemble"], &sharded);
    assert!(!ok, "--assemble must refuse while shard 1 has not run");
    assert!(
        err.contains(&format!(
            "{} of {} work units are missing",
            missing.len(),
            units.len()
        )) && err.contains(&missing[0].id()),
        "{err}"
    );
    let (ok, err) = study(&["--shard", "1/4"], &sharded);
    assert!(ok, "{err}");
    let (ok, err) = study(&["--assemble"], &sharded);
    assert!(ok, "{err}");
    let (a, b) = (csv_tables(&whole), csv_tables(&sharded));
    let names: Vec<&String> = a.iter().map(|(n, _)| n).collect();
    assert_eq!(a.len(), 13, "the tables of --quick: {names:?}");
    assert!(a == b, "sharded tables differ from the unsharded run's");
    // The assembled report says it ran no unit and lists the shards' timing tables, each with the
    // units and seconds its CSV states (read here with the csv crate).
    let md = crate::common::read_report(&sharded);
    assert!(
        md.contains(&format!(
            "None of the {} work units ran in this invocation: every result was already in the folder",
            units.len()
        )),
        "{md}"
    );
    let mut listed = Vec::new();
    let mut shard_units = 0;
    for i in 0..4 {
        let file = format!("timings-shard-{i}-of-4.csv");
        let mut rdr = csv::Reader::from_path(sharded.join(&file)).expect("shard timings");
        let rows: Vec<csv::StringRecord> = rdr.records().map(|r| r.expect("row")).collect();
        let row = |phase: &str| rows.iter().find(|r| &r[0] == phase).expect(phase).clone();
        let (work, total) = (row("work units (parallel)"), row("total"));
        let n: usize = work[3].parse().unwrap();
        shard_units += n;
        let secs = |r: &csv::StringRecord| r[2].parse::<f64>().unwrap();
        listed.push(format!(
            "[{file}]({file}) ({n} unit{} in {:.1} s of wall time, {:.1} s in all)",
            if n == 1 { "" } else { "s" },
            secs(&work),
            secs(&total)
        ));
    }
    assert_eq!(shard_units, units.len(), "the shards ran every unit once");
    let expected = format!(
        "The shards' own timing tables are in this folder: {}.",
        listed.join(", ")
    );
    assert!(md.contains(&expected), "{expected}\nnot in\n{md}");
}

/// Inside a Slurm array task (SLURM_ARRAY_TASK_ID / SLURM_ARRAY_TASK_COUNT set, no --shard) only that
/// task's shard runs; an ID outside the count is refused with the array spelling to use.
#[test]
fn slurm_array_environment_selects_the_shard() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o");
    let run = |id: &str, count: &str| {
        Spinedrr::new()
            .args(["study", "--quick", "--threads", "1", "--out"])
            .arg(&out)
            .env("SLURM_ARRAY_TASK_ID", id)
            .env("SLURM_ARRAY_TASK_COUNT", count)
            .outcome()
    };
    let (ok, err) = run("1", "3");
    assert!(ok, "{err}");
    let cfg = StudyConfig::quick();
    let units = enumerate_units(&cfg).unwrap();
    let mine: BTreeSet<String> = units_of(&cfg, &units, Shard::new(1, 3).unwrap())
        .iter()
        .map(|u| format!("{}.json", u.id()))
        .collect();
    let written: BTreeSet<String> = std::fs::read_dir(out.join("units"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(written, mine);
    assert!(out.join("timings-shard-1-of-3.csv").is_file());
    let (ok, err) = run("3", "3");
    assert!(!ok);
    assert!(err.contains("--array=0-2"), "{err}");
}
