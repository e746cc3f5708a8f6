//! `groupforward bench ...`: measurements written as CSV and Markdown.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::Subcommand;
use groupforward::group::blobs::blobs;
use groupforward::group::hdbscan::{hdbscan, HdbscanParams};
use groupforward::recon::metrics::adjusted_rand_index;

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// HDBSCAN time and agreement against the Python `hdbscan` package, side by side on the same
    /// seeded 8-d blobs (sklearn's make_blobs recipe).
    Grouping {
        /// Numbers of points, comma separated.
        #[arg(
            long,
            value_delimiter = ',',
            default_value = "5000,10000,20000,50000,100000,200000"
        )]
        sizes: Vec<usize>,
        #[arg(long, default_value_t = 8)]
        dims: usize,
        #[arg(long, default_value_t = 12)]
        centers: usize,
        #[arg(long, default_value_t = 60)]
        min_cluster_size: usize,
        #[arg(long, default_value_t = 10)]
        min_samples: usize,
        /// Python with `hdbscan` installed (`make setup` puts it in .venv); `none` skips the
        /// reference.
        #[arg(long, default_value = ".venv/bin/python")]
        python: String,
        /// Output prefix: writes `<out>.csv` and `<out>.md`.
        #[arg(long, default_value = "bench/grouping")]
        out: PathBuf,
    },
}

pub fn run(command: BenchCommand) -> Result<()> {
    match command {
        BenchCommand::Grouping {
            sizes,
            dims,
            centers,
            min_cluster_size,
            min_samples,
            python,
            out,
        } => grouping(
            &sizes,
            dims,
            centers,
            min_cluster_size,
            min_samples,
            &python,
            &out,
        ),
    }
}

fn as_ari_labels(labels: &[i32]) -> Vec<u32> {
    labels.iter().map(|&l| (l + 1) as u32).collect()
}

struct Reference {
    seconds: f64,
    labels: Vec<i32>,
    version: String,
}

fn python_reference(
    python: &str,
    dir: &Path,
    points: &[f32],
    dims: usize,
    min_cluster_size: usize,
    min_samples: usize,
) -> Result<Reference> {
    let input = dir.join("points.f32");
    let output = dir.join("labels.i32");
    let bytes: Vec<u8> = points.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(&input, bytes)?;
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/hdbscan_reference.py");
    let result = std::process::Command::new(python)
        .arg(&script)
        .arg(&input)
        .arg(dims.to_string())
        .arg(min_cluster_size.to_string())
        .arg(min_samples.to_string())
        .arg(&output)
        .output()
        .with_context(|| format!("running {python} {}", script.display()))?;
    if !result.status.success() {
        bail!(
            "the Python reference failed: {}",
            String::from_utf8_lossy(&result.stderr)
        );
    }
    let report: serde_json::Value = serde_json::from_slice(&result.stdout)?;
    let labels = std::fs::read(&output)?
        .chunks_exact(4)
        .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Ok(Reference {
        seconds: report["seconds"].as_f64().unwrap_or(f64::NAN),
        labels,
        version: report["version"].as_str().unwrap_or("?").to_owned(),
    })
}

fn grouping(
    sizes: &[usize],
    dims: usize,
    centers: usize,
    min_cluster_size: usize,
    min_samples: usize,
    python: &str,
    out: &Path,
) -> Result<()> {
    if let Some(parent) = out.parent() {
        std::fs::create_dir_all(parent)?;
    }
    let scratch = tempfile::tempdir()?;
    let params = HdbscanParams {
        min_cluster_size,
        min_samples,
        allow_single_cluster: false,
    };
    let threads = rayon::current_num_threads();
    let mut csv = String::from(
        "points,dims,clusters_true,rust_seconds,rust_clusters,rust_noise,python_seconds,python_clusters,python_noise,speedup,ari_rust_python,ari_rust_truth,ari_python_truth\n",
    );
    let mut md = format!(
        "HDBSCAN on {dims}-d blobs ({centers} centres, min_cluster_size {min_cluster_size}, min_samples {min_samples}), {threads} threads, best of two fits each.\n\n\
         | points | groupforward (s) | Python hdbscan (s) | speed-up | ARI vs Python | ARI vs truth (ours / Python) |\n\
         | ---: | ---: | ---: | ---: | ---: | ---: |\n"
    );
    let mut version = String::from("not run");
    for &n in sizes {
        let (points, truth) = blobs(n, dims, centers, 1.0, n as u64);
        // Best of two runs, as for the Python side.
        let mut rust_seconds = f64::INFINITY;
        let mut ours = None;
        for _ in 0..2 {
            let started = Instant::now();
            let result = hdbscan(&points, dims, &params)?;
            rust_seconds = rust_seconds.min(started.elapsed().as_secs_f64());
            ours = Some(result);
        }
        let ours = ours.context("no run")?;
        let rust_noise = ours.labels.iter().filter(|l| **l < 0).count();
        let ari_truth = adjusted_rand_index(&as_ari_labels(&ours.labels), &truth)?;
        let reference = if python == "none" {
            None
        } else {
            Some(python_reference(
                python,
                scratch.path(),
                &points,
                dims,
                min_cluster_size,
                min_samples,
            )?)
        };
        let (py_seconds, py_clusters, py_noise, ari_pair, ari_py_truth) = match &reference {
            Some(r) => {
                version = r.version.clone();
                (
                    r.seconds,
                    r.labels.iter().copied().max().unwrap_or(-1) + 1,
                    r.labels.iter().filter(|l| **l < 0).count(),
                    adjusted_rand_index(&as_ari_labels(&ours.labels), &as_ari_labels(&r.labels))?,
                    adjusted_rand_index(&as_ari_labels(&r.labels), &truth)?,
                )
            }
            None => (f64::NAN, -1, 0, f64::NAN, f64::NAN),
        };
        let speedup = py_seconds / rust_seconds;
        csv.push_str(&format!(
            "{n},{dims},{centers},{rust_seconds:.4},{},{rust_noise},{py_seconds:.4},{py_clusters},{py_noise},{speedup:.2},{ari_pair:.5},{ari_truth:.5},{ari_py_truth:.5}\n",
            ours.n_clusters
        ));
        md.push_str(&format!(
            "| {n} | {rust_seconds:.3} | {py_seconds:.3} | {speedup:.1}× | {ari_pair:.4} | {ari_truth:.4} / {ari_py_truth:.4} |\n"
        ));
        eprintln!(
            "{n:>7} points: groupforward {rust_seconds:.3} s ({} clusters, {rust_noise} noise), Python {py_seconds:.3} s ({py_clusters} clusters, {py_noise} noise), {speedup:.1}x, ARI {ari_pair:.4}",
            ours.n_clusters
        );
    }
    md.push_str(&format!(
        "\nPython hdbscan {version}. Reproduce: `groupforward bench grouping`.\n"
    ));
    let csv_path = out.with_extension("csv");
    let md_path = out.with_extension("md");
    std::fs::File::create(&csv_path)?.write_all(csv.as_bytes())?;
    std::fs::File::create(&md_path)?.write_all(md.as_bytes())?;
    print!("{md}");
    println!("wrote {} and {}", csv_path.display(), md_path.display());
    Ok(())
}
