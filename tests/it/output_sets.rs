//! Stale, mixed or lost outputs of `render` and `compare`, through the real binary: a run that cannot
//! write every file writes none, the main sidecar (written last) lists its companions, temporaries of
//! killed runs are removed, and `compare` refuses or skips masks of another render.

use std::path::{Path, PathBuf};

use glam::DVec3;
use spinedrr::anatomy::{TriMesh, write_mesh};
use spinedrr::io::Sidecar;

fn s(p: &Path) -> String {
    p.display().to_string()
}

fn cube(dir: &Path) -> String {
    let path = dir.join("c.stl");
    let m = TriMesh::cuboid("c", DVec3::splat(-10.0), DVec3::new(10.0, 12.0, 14.0));
    write_mesh(&path, &m).unwrap();
    s(&path)
}

/// `render --mesh MESH --out OUT EXTRA…`, expected to succeed.
fn render(mesh: &str, out: &Path, extra: &[&str]) {
    let out = s(out);
    let args = [&["render", "--mesh", mesh, "--out", &out][..], extra].concat();
    let (ok, err) = crate::common::run(&args);
    assert!(ok, "{err}");
}

/// The files of `dir` whose names hold `.tmp-` (atomic-write temporaries).
fn temporaries(dir: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.file_name().unwrap().to_string_lossy().contains(".tmp-"))
        .collect()
}

#[test]
fn a_render_that_cannot_write_its_set_leaves_the_old_set_intact() {
    let d = tempfile::tempdir().unwrap();
    let mesh = cube(d.path());
    let out = d.path().join("o.tiff");
    render(&mesh, &out, &["--masks"]);
    let before: Vec<(PathBuf, Vec<u8>)> = ["o.tiff", "o.png", "o_mask.png", "o_mask.json"]
        .iter()
        .map(|f| d.path().join(f))
        .map(|p| (p.clone(), std::fs::read(&p).unwrap()))
        .collect();
    // The sidecar's path blocked by a folder; and a mask's. Each blocked file is put back afterwards
    // (the image beside a missing sidecar would be refused as not spinedrr's before the mask is reached).
    for blocked in ["o.json", "o_mask_c.json"] {
        let b = d.path().join(blocked);
        let saved = std::fs::read(&b).unwrap();
        std::fs::remove_file(&b).unwrap();
        std::fs::create_dir(&b).unwrap();
        let args = [
            "render",
            "--mesh",
            &mesh,
            "--perturb",
            "df=300",
            "--masks",
            "--out",
            &s(&out),
        ];
        let (ok, err) = crate::common::run(&args);
        assert!(!ok && !err.contains("panicked"), "{err}");
        assert!(err.contains(blocked) && err.contains("directory"), "{err}");
        for (p, bytes) in &before {
            assert_eq!(&std::fs::read(p).unwrap(), bytes, "{} changed", p.display());
        }
        assert!(temporaries(d.path()).is_empty());
        std::fs::remove_dir(&b).unwrap();
        std::fs::write(&b, saved).unwrap();
    }
}

#[test]
fn the_sidecar_is_written_last_and_lists_its_companions() {
    let d = tempfile::tempdir().unwrap();
    let mesh = cube(d.path());
    let out = d.path().join("o.tiff");
    // A temporary left by a killed run (process ids above the kernel's pid_max are never alive) and
    // one of this very test process, which is alive.
    let dead = d.path().join(".o.tiff.tmp-4999999");
    let live = d.path().join(format!(".o.tiff.tmp-{}", std::process::id()));
    std::fs::write(&dead, b"partial").unwrap();
    std::fs::write(&live, b"in progress").unwrap();
    render(&mesh, &out, &["--masks", "--depth"]);
    assert!(!dead.exists() && live.exists());
    std::fs::remove_file(&live).unwrap();
    let sc = Sidecar::read(&d.path().join("o.json")).unwrap();
    let mut listed = sc.companions.clone();
    listed.sort();
    let mut on_disk: Vec<String> = std::fs::read_dir(d.path())
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("o") && n != "o.json")
        .collect();
    on_disk.sort();
    assert_eq!(listed, on_disk);
    assert!(
        listed.contains(&"o_depth.tiff".to_string()) && listed.contains(&"o_mask_c.png".into())
    );
    // The set's files are newer than none of its companions: the sidecar is the last written.
    let mtime = |n: &str| {
        std::fs::metadata(d.path().join(n))
            .unwrap()
            .modified()
            .unwrap()
    };
    assert!(listed.iter().all(|n| mtime(n) <= mtime("o.json")));
    // A render without masks lists none: the masks beside it are not part of its set.
    render(&mesh, &out, &[]);
    let sc = Sidecar::read(&d.path().join("o.json")).unwrap();
    assert_eq!(sc.companions, ["o.tiff", "o.png"]);
}

#[test]
fn compare_refuses_or_skips_masks_of_another_render() {
    let d = tempfile::tempdir().unwrap();
    let mesh = cube(d.path());
    let (a, b) = (d.path().join("a.tiff"), d.path().join("b.tiff"));
    render(&mesh, &a, &["--masks"]);
    render(&mesh, &b, &["--masks", "--perturb", "df=300"]);
    let cmp = |extra: &[&str]| {
        let args = ["compare", "--reference", &s(&a), "--perturbed", &s(&b)];
        let out = s(&d.path().join("cmp"));
        crate::common::run(&[&args[..], &["--out", &out], extra].concat())
    };
    let (ok, err) = cmp(&[]);
    assert!(ok, "{err}");
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.path().join("cmp/metrics.json")).unwrap())
            .unwrap();
    assert!(
        metrics["silhouettes"].to_string().contains("\"c\""),
        "{metrics}"
    );
    assert_eq!(metrics["companions"][0], "absdiff.tiff");
    // B re-rendered under another K without masks: its old masks are stale.
    render(&mesh, &b, &["--perturb", "df=-300"]);
    let (ok, err) = cmp(&[]);
    assert!(ok, "{err}");
    assert!(
        err.contains("skipping mask") && err.contains("b_mask_c.png"),
        "{err}"
    );
    // Named explicitly, a stale mask is refused, naming both files.
    let pair = format!(
        "c={}:{}",
        s(&d.path().join("a_mask_c.png")),
        s(&d.path().join("b_mask_c.png"))
    );
    let (ok, err) = cmp(&["--masks", &pair]);
    assert!(!ok && !err.contains("panicked"), "{err}");
    assert!(
        err.contains("b_mask_c.png") && err.contains("b.tiff") && err.contains("K"),
        "{err}"
    );
    // The failed compare left the earlier comparison's marker in place... and its set complete.
    assert!(d.path().join("cmp/metrics.json").exists());
    assert!(temporaries(&d.path().join("cmp")).is_empty());
}

/// A 128 × 128 detector (64 KiB float images), so a set fits a small tmpfs.
const SMALL_DETECTOR: &str = "[detector]\nwidth = 128\nheight = 128\npixel_spacing_mm = [2.4, 2.4]\n\
sdd_mm = 1350.0\n[[view]]\nname = \"ap\"\nsource_mm = [0.0, -1000.0, 0.0]\ntarget_mm = [0.0, 0.0, 0.0]\n\
up = [0.0, 0.0, 1.0]\n";

/// A re-render that runs out of disk space (a 1 MiB tmpfs filled up, in a mount namespace of its own)
/// fails naming the cause and leaves the earlier set whole: every file byte for byte, the sidecar
/// present, no staging folder left.
#[test]
fn a_render_that_runs_out_of_space_leaves_the_earlier_set_whole() {
    let root = crate::common::is_root();
    if !root {
        eprintln!("skipping: mounting a tmpfs needs root");
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let mesh = cube(d.path());
    let geometry = d.path().join("small.toml");
    std::fs::write(&geometry, SMALL_DETECTOR).unwrap();
    let (mnt, snap) = (d.path().join("mnt"), d.path().join("snap"));
    std::fs::create_dir_all(&mnt).unwrap();
    std::fs::create_dir_all(&snap).unwrap();
    let render = |spec: &str| {
        format!(
            "\"$B\" render --mesh '{mesh}:0.05' --geometry '{}' --perturb {spec} --masks --depth --out \
             '{}/a.tiff'",
            s(&geometry),
            s(&mnt)
        )
    };
    let script = format!(
        "set -u\nB='{bin}'\nmount -t tmpfs -o size=1m tmpfs '{m}' || {{ echo MOUNT-FAILED; exit 0; }}\n\
         {first} || exit 11\ncp -a '{m}'/. '{snap}'/\n\
         dd if=/dev/zero of='{m}/fill' bs=4096 2>/dev/null\n\
         {second} 2> '{snap_err}' && exit 12\n\
         rm -f '{m}/fill'\n\
         for f in '{snap}'/*; do cmp \"$f\" '{m}'/\"$(basename \"$f\")\" || exit 13; done\n\
         ls -A '{m}' | grep -q staging && exit 14\n\
         [ \"$(ls -A '{m}' | wc -l)\" = \"$(ls -A '{snap}' | wc -l)\" ] || exit 15\n\
         echo SET-INTACT\n",
        bin = env!("CARGO_BIN_EXE_spinedrr"),
        m = s(&mnt),
        snap = s(&snap),
        snap_err = s(&d.path().join("second.err")),
        first = render("none"),
        second = render("df=300"),
    );
    let o = std::process::Command::new("unshare")
        .env("SPINEDRR_CACHE_DIR", crate::common::MESH_CACHE)
        .args(["--mount", "--propagation", "private", "sh", "-c", &script])
        .output()
        .expect("unshare");
    let stdout = String::from_utf8_lossy(&o.stdout);
    if stdout.contains("MOUNT-FAILED") || !o.status.success() && o.status.code() == Some(1) {
        eprintln!(
            "skipping: no tmpfs in a mount namespace here: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        return;
    }
    assert!(
        stdout.contains("SET-INTACT"),
        "exit {:?}: {stdout} {}",
        o.status.code(),
        String::from_utf8_lossy(&o.stderr)
    );
    let err = std::fs::read_to_string(d.path().join("second.err")).unwrap();
    assert!(
        err.contains("No space left") && !err.contains("panicked"),
        "{err}"
    );
    // The snapshot is a complete set: its sidecar lists every other file.
    let sc = Sidecar::read(&snap.join("a.json")).unwrap();
    assert!(
        sc.companions.contains(&"a_depth.tiff".to_string()),
        "{sc:?}"
    );
}

/// Renders of two perturbations to one name at once end as one render's complete set: the sidecar's
/// perturbation is the image's (the image equals a render of that perturbation alone), and every
/// companion belongs to it.
#[test]
fn concurrent_renders_to_one_name_leave_one_consistent_set() {
    let d = tempfile::tempdir().unwrap();
    let mesh = format!("{}:0.05", cube(d.path()));
    let geometry = d.path().join("small.toml");
    std::fs::write(&geometry, SMALL_DETECTOR).unwrap();
    let g = s(&geometry);
    let out = d.path().join("o.tiff");
    for round in 0..4 {
        let children: Vec<_> = ["none", "df=300"]
            .iter()
            .map(|spec| {
                crate::common::Spinedrr::new()
                    .args(["render", "--mesh", &mesh, "--geometry", &g, "--masks"])
                    .args(["--perturb", spec, "--out"])
                    .arg(&out)
                    .command()
                    .stderr(std::process::Stdio::piped())
                    .spawn()
                    .unwrap()
            })
            .collect();
        for c in children {
            let o = c.wait_with_output().unwrap();
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        }
        let sc = Sidecar::read(&d.path().join("o.json")).unwrap();
        let alone = d.path().join(format!("alone{round}.tiff"));
        render(
            &mesh,
            &alone,
            &[
                "--geometry",
                &g,
                "--masks",
                "--perturb",
                &sc.perturbation_spec,
            ],
        );
        for (a, b) in [
            ("o.tiff", "alone{round}.tiff"),
            ("o_mask_c.png", "alone{round}_mask_c.png"),
        ] {
            let b = b.replace("{round}", &round.to_string());
            assert_eq!(
                std::fs::read(d.path().join(a)).unwrap(),
                std::fs::read(d.path().join(&b)).unwrap(),
                "round {round}: {a} is not the render its sidecar describes ({})",
                sc.perturbation_spec
            );
        }
        assert!(staging_dirs(d.path()).is_empty());
    }
}

fn staging_dirs(dir: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.to_string_lossy().contains(".staging-"))
        .collect()
}
