//! Every criterion benchmark of spinedrr in one binary: one compile and one link of the library instead of
//! seven (`make test` builds every target; issue #30).
//!
//! `cargo bench --bench all` runs them all (`make bench`); `cargo bench --bench all -- MODULE` runs one
//! module: `calibration`, `intensity`, `metrics`, `python_overhead`, `real_ct`, `registration`, `render`,
//! `spectral` or `volume`.
//! Every benchmark's id starts with its module's name, so a longer filter (`render/L3`, `volume/decimate`)
//! runs that module's set-up and criterion times the benchmarks it matches. A filter that starts with no
//! module's name runs every module's set-up (criterion still times only what it matches).

use criterion::Criterion;

mod calibration;
mod intensity;
mod metrics;
mod python_overhead;
mod real_ct;
mod registration;
mod render;
mod spectral;
mod volume;

type Module = (&'static str, fn(&mut Criterion));

const MODULES: [Module; 9] = [
    ("calibration", calibration::run),
    ("intensity", intensity::run),
    ("metrics", metrics::run),
    ("python_overhead", python_overhead::run),
    ("real_ct", real_ct::run),
    ("registration", registration::run),
    ("render", render::run),
    ("spectral", spectral::run),
    ("volume", volume::run),
];

/// criterion's options that take a value (the value is not the filter).
const VALUED: [&str; 16] = [
    "--save-baseline",
    "--baseline",
    "--baseline-lenient",
    "--load-baseline",
    "--sample-size",
    "--warm-up-time",
    "--measurement-time",
    "--nresamples",
    "--noise-threshold",
    "--confidence-level",
    "--significance-level",
    "--plotting-backend",
    "--output-format",
    "--color",
    "--format",
    "--profile-time",
];

/// The filter criterion will apply: the first argument that is neither an option nor an option's value.
fn filter(args: &[String]) -> Option<&str> {
    let mut skip = false;
    for a in args {
        if std::mem::take(&mut skip) {
            continue;
        }
        if a.starts_with('-') {
            skip = VALUED.contains(&a.as_str());
        } else {
            return Some(a);
        }
    }
    None
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let named = filter(&args).and_then(|f| MODULES.iter().find(|(m, _)| f.starts_with(m)));
    let mut c = Criterion::default().configure_from_args();
    for (name, run) in &MODULES {
        if named.is_none_or(|(m, _)| m == name) {
            run(&mut c);
        }
    }
    c.final_summary();
}
