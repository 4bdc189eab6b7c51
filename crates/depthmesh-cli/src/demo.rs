//! `depthmesh demo`: the thesis's experiments (Table 4.1) on built-in scenes,
//! with no external data needed for the first one.

use crate::out_dir;
use crate::planes::PlanesArgs;
use crate::simulate::{self, MapKind, SimulateArgs};
use anyhow::{bail, Result};
use clap::Args;
use depthmesh::sim::{NoiseModel, PathSpec};
use serde_json::{Map, Value};
use std::path::{Path, PathBuf};

/// The table scene, built into the binary so the demo runs from anywhere.
const TABLE_SCENE: &str = include_str!("../../../scenes/table.toml");
/// The bunnies scene; its mesh comes from `--bunny`.
const BUNNIES_SCENE: &str = include_str!("../../../scenes/bunnies.toml");
/// The bunnies scene whose middle bunny goes away in dynamic runs.
const BUNNIES_REMOVAL_SCENE: &str = include_str!("../../../scenes/bunnies_removal.toml");

/// Flags of `depthmesh demo`.
#[derive(Args, Debug, Clone)]
pub struct DemoArgs {
    /// Output folder (one subfolder per run).
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Stanford bunny mesh; with it the bunnies runs (2 and 3 of Table 4.1) and
    /// an object-removal run are added.
    #[arg(long)]
    pub bunny: Option<PathBuf>,
    /// Replace the runs of an earlier demo in --out.
    #[arg(long)]
    pub force: bool,
}

/// One experiment of the demo.
struct Experiment {
    name: &'static str,
    scene: &'static str,
    source: &'static str,
    iterations: u32,
    noise: NoiseModel,
    dynamic: bool,
}

/// Runs the experiments and prints a summary table.
pub fn run(args: &DemoArgs, quiet: bool) -> Result<()> {
    let thesis_noise = NoiseModel::ZBuffer { sigma: 0.002 };
    let mut experiments = vec![Experiment {
        name: "run1-table",
        scene: TABLE_SCENE,
        source: "scenes/table.toml",
        iterations: 30,
        noise: NoiseModel::None,
        dynamic: false,
    }];
    if args.bunny.is_some() {
        let runs = [
            ("run2-bunnies", BUNNIES_SCENE, "scenes/bunnies.toml", false),
            (
                "run3-bunnies-dynamic",
                BUNNIES_SCENE,
                "scenes/bunnies.toml",
                true,
            ),
            (
                "run4-bunnies-removal",
                BUNNIES_REMOVAL_SCENE,
                "scenes/bunnies_removal.toml",
                true,
            ),
        ];
        for (name, scene, source, dynamic) in runs {
            experiments.push(Experiment {
                name,
                scene,
                source,
                iterations: 50,
                noise: thesis_noise,
                dynamic,
            });
        }
    } else if !quiet {
        eprintln!("note: runs 2 and 3 (bunnies) need the bunny mesh: pass --bunny PATH");
    }

    if let Some(bunny) = &args.bunny {
        if !bunny.is_file() {
            bail!("--bunny {}: no such file", bunny.display());
        }
    }
    // Every run's scene and folder is checked before the first starts.
    let mut runs = Vec::new();
    for e in &experiments {
        let sim = SimulateArgs {
            scene: PathBuf::from(e.source),
            map: MapKind::Mabdi,
            iterations: e.iterations,
            noise: e.noise,
            dynamic: e.dynamic,
            seed: 0,
            bunny: args.bunny.clone(),
            path: PathSpec::Helix,
            threshold: None,
            voxel: 0.01,
            keep_removed: false,
            no_settle: false,
            no_smooth: false,
            track: false,
            track_against: simulate::TrackModel::Map,
            save_frames: false,
            planes: PlanesArgs::default(),
            dashboard: true,
            view: false,
            out: args.out.join(e.name),
            force: args.force,
            export: Default::default(),
            bounded: Default::default(),
            memory: Default::default(),
            store: Default::default(),
        };
        out_dir::check(&sim.out, sim.force)?;
        let scene = simulate::load_scene(
            Path::new(e.source),
            Some(e.scene),
            sim.dynamic,
            sim.bunny.as_deref(),
        )?;
        runs.push((e.name, sim, scene));
    }
    let mut rows = Vec::new();
    for (name, sim, scene) in &runs {
        let result = simulate::run_scene(sim, scene, quiet)?;
        rows.push((*name, result.summary));
    }
    print_table(&rows);
    println!("outputs in {}", args.out.display());
    Ok(())
}

fn print_table(rows: &[(&str, Map<String, Value>)]) {
    let num = |m: &Map<String, Value>, k: &str| m.get(k).and_then(Value::as_f64).unwrap_or(0.0);
    println!(
        "{:<22} {:>5} {:>12} {:>12} {:>8} {:>8} {:>10} {:>8}",
        "run", "iters", "elements", "naive", "ratio", "removed", "within5mm", "fps"
    );
    for (name, m) in rows {
        println!(
            "{:<22} {:>5} {:>12} {:>12} {:>7.1}% {:>8} {:>9.1}% {:>8.1}",
            name,
            num(m, "iterations"),
            num(m, "triangles"),
            num(m, "naive_elements"),
            100.0 * num(m, "elements_vs_naive"),
            num(m, "removed_elements"),
            100.0 * num(m, "surface_within_5mm"),
            num(m, "fps"),
        );
    }
}
