//! The phantom mesh cache: a phantom taken from it is the phantom built afresh, bit for bit; an entry is
//! used only for the same options and code; corrupt, foreign or unwritable entries cost a rebuild, never a
//! wrong phantom or a failure.

use std::path::Path;

use spinedrr::anatomy::phantom::mesh_identity;
use spinedrr::anatomy::phantom_cache::{CODE_DIGEST, KEEP_DIGESTS};
use spinedrr::anatomy::{Level, MeshCache, Phantom, PhantomOptions, build_phantom_with};

use crate::common::Spinedrr;

/// Two adjacent levels with disc and soft tissue on a coarse grid: every kind of mesh, quickly.
fn small() -> PhantomOptions {
    PhantomOptions {
        levels: vec![Level::L3, Level::L2],
        voxel_mm: 1.5,
        soft_tissue: true,
        simplify_edge_mm: 2.0,
        ..PhantomOptions::default()
    }
}

/// One level alone (no disc, no soft tissue) on [`small`]'s coarse grid.
fn one_level(level: Level) -> PhantomOptions {
    PhantomOptions {
        levels: vec![level],
        discs: false,
        soft_tissue: false,
        ..small()
    }
}

/// The whole phantom written out: `{:?}` prints every float so that it reads back to the same bits, so
/// equal texts are equal phantoms (meshes, labels, landmarks, poses, shapes).
fn text(p: &Phantom) -> String {
    format!("{p:?}")
}

fn fresh(opts: &PhantomOptions) -> String {
    text(&build_phantom_with(opts, None).unwrap())
}

/// The entries (`.bin`; beside them are their lock files) of this build.
fn entries(root: &Path) -> Vec<std::path::PathBuf> {
    let dir = root.join("phantom").join(CODE_DIGEST);
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .map(|d| {
            d.map(|e| e.unwrap().path())
                .filter(|p| p.extension().is_some_and(|x| x == "bin"))
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

#[test]
fn a_cached_phantom_is_the_fresh_one_bit_for_bit_and_is_reused() {
    let dir = tempfile::tempdir().unwrap();
    let cache = MeshCache::new(dir.path());
    let want = fresh(&small());
    assert!(want.contains("soft_tissue: Some") && want.contains("L2-L3_disc"));
    let first = text(&build_phantom_with(&small(), Some(&cache)).unwrap());
    assert_eq!(cache.stats(), (0, 1, 0));
    assert_eq!(entries(dir.path()).len(), 1);
    let second = text(&build_phantom_with(&small(), Some(&cache)).unwrap());
    assert_eq!(cache.stats(), (1, 1, 0), "the second build is read back");
    assert!(first == want && second == want);
    // The levels' order and repetition do not make another phantom.
    let shuffled = PhantomOptions {
        levels: vec![Level::L2, Level::L3, Level::L2],
        ..small()
    };
    assert_eq!(
        text(&build_phantom_with(&shuffled, Some(&cache)).unwrap()),
        want
    );
    assert_eq!(cache.stats(), (2, 1, 0));
}

#[test]
fn any_changed_option_is_a_miss_with_its_own_entry() {
    let dir = tempfile::tempdir().unwrap();
    let cache = MeshCache::new(dir.path());
    build_phantom_with(&small(), Some(&cache)).unwrap();
    let mut morph = small();
    morph.morphometry.shape.endplate_concavity_mm += 0.1;
    let changed = [
        PhantomOptions {
            cortical_mm: 1.0,
            ..small()
        },
        PhantomOptions {
            soft_tissue: false,
            ..small()
        },
        PhantomOptions {
            lordosis_deg: 4.0 + 1e-12,
            ..small()
        },
        morph,
    ];
    for (i, o) in changed.iter().enumerate() {
        let got = text(&build_phantom_with(o, Some(&cache)).unwrap());
        assert_eq!(
            cache.stats(),
            (0, i + 2, 0),
            "option set {i} was served from the cache"
        );
        assert_eq!(got, fresh(o), "option set {i}");
    }
    assert_eq!(entries(dir.path()).len(), 1 + changed.len());
}

#[test]
fn a_corrupt_or_foreign_entry_is_rebuilt_not_used() {
    let dir = tempfile::tempdir().unwrap();
    let cache = MeshCache::new(dir.path());
    let other = one_level(Level::L4);
    build_phantom_with(&small(), Some(&cache)).unwrap();
    build_phantom_with(&other, Some(&cache)).unwrap();
    let entry = cache.entry_path(&mesh_identity(&small()));
    assert!(entry.exists(), "{}", entry.display());
    let good = std::fs::read(&entry).unwrap();
    let want = fresh(&small());
    let damaged: Vec<(&str, Vec<u8>)> = vec![
        ("truncated", good[..good.len() / 2].to_vec()),
        ("one bit flipped", {
            let mut b = good.clone();
            let i = b.len() / 3;
            b[i] ^= 1;
            b
        }),
        ("empty", Vec::new()),
        ("another phantom's entry", {
            let foreign = entries(dir.path())
                .into_iter()
                .find(|p| *p != entry)
                .unwrap();
            std::fs::read(foreign).unwrap()
        }),
    ];
    for (k, (what, bytes)) in damaged.into_iter().enumerate() {
        std::fs::write(&entry, bytes).unwrap();
        let got = text(&build_phantom_with(&small(), Some(&cache)).unwrap());
        assert_eq!(got, want, "{what}");
        assert_eq!(cache.stats().2, k + 1, "{what} was not rejected");
        assert_eq!(
            std::fs::read(&entry).unwrap(),
            good,
            "{what}: entry rewritten"
        );
    }
}

#[test]
fn an_unwritable_cache_still_builds_the_phantom() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("not-a-directory");
    std::fs::write(&root, "a file where the cache should be").unwrap();
    let cache = MeshCache::new(&root);
    let o = one_level(Level::L1);
    assert_eq!(
        text(&build_phantom_with(&o, Some(&cache)).unwrap()),
        fresh(&o)
    );
    assert_eq!(
        std::fs::read_to_string(&root).unwrap(),
        "a file where the cache should be"
    );
}

#[test]
fn old_code_digests_are_pruned_and_nothing_else_is_touched() {
    let dir = tempfile::tempdir().unwrap();
    let base = dir.path().join("phantom");
    let now = std::time::SystemTime::now();
    let olds: Vec<_> = (0..KEEP_DIGESTS + 2)
        .map(|i| {
            let d = base.join(format!("{:032x}", i + 1));
            std::fs::create_dir_all(&d).unwrap();
            std::fs::write(d.join("x.bin"), "old").unwrap();
            let age = std::time::Duration::from_secs(3600 * (i as u64 + 1));
            std::fs::File::open(&d)
                .unwrap()
                .set_modified(now - age)
                .unwrap();
            d
        })
        .collect();
    let keep_mine = base.join("not-a-digest");
    std::fs::create_dir_all(&keep_mine).unwrap();
    let cache = MeshCache::new(dir.path());
    let o = one_level(Level::L5);
    build_phantom_with(&o, Some(&cache)).unwrap();
    // This build's directory plus the newest KEEP_DIGESTS − 1 others stay.
    let kept: Vec<bool> = olds.iter().map(|d| d.exists()).collect();
    let mut want = vec![false; olds.len()];
    want[..KEEP_DIGESTS - 1].fill(true);
    assert_eq!(kept, want);
    assert!(keep_mine.exists() && cache.digest_dir().exists());
}

#[test]
fn the_cli_caches_where_told_and_writes_the_same_meshes() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let build = |out: &str, cache_dir: &Path| {
        let o = Spinedrr::new()
            .args(["phantom", "--levels", "L1,L2", "--voxel-mm", "1.5", "--out"])
            .arg(dir.path().join(out))
            .env("SPINEDRR_CACHE_DIR", cache_dir)
            .current_dir(dir.path())
            .output();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let mut files: Vec<_> = std::fs::read_dir(dir.path().join(out))
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        files
            .iter()
            .map(|f| (f.file_name().unwrap().to_owned(), std::fs::read(f).unwrap()))
            .collect::<Vec<_>>()
    };
    let miss = build("a", &cache);
    assert_eq!(entries(&cache).len(), 1, "one entry written");
    let hit = build("b", &cache);
    let off = build("c", Path::new("off"));
    assert!(miss.len() >= 6, "{} files", miss.len());
    assert!(
        miss == hit && hit == off,
        "cached and fresh phantoms write alike"
    );
    assert!(
        !dir.path().join("off").exists(),
        "`off` is not a directory name"
    );
    assert_eq!(entries(&cache).len(), 1);
}
