//! `depthmesh`: depth images in, compact triangle-mesh maps out.

mod bench;
mod bounded;
mod cluster;
mod dataset_args;
mod demo;
mod draw;
mod eval;
mod export;
mod info;
mod map_args;
mod memory;
mod out_dir;
mod planes;
mod progress;
mod reconstruct;
mod run;
mod serve;
mod simplify;
mod simulate;
mod status;
mod store;
mod stream;
mod study;
mod views;
mod watch;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// Turn depth images into compact, incrementally updated triangle-mesh maps.
#[derive(Parser, Debug)]
#[command(name = "depthmesh", version, about)]
struct Cli {
    /// Hide progress bars.
    #[arg(long, global = true)]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Map a simulated sensor circling a scene file.
    Simulate(simulate::SimulateArgs),
    /// Map a recorded depth sequence (7-Scenes or TUM layout), with its poses or tracked ones.
    Reconstruct(reconstruct::ReconstructArgs),
    /// Run the thesis's experiments on the built-in scenes and summarise them.
    Demo(demo::DemoArgs),
    /// Measure speed (figures as JSON): MABDI on a generated scene, voxel
    /// planes and depth codecs on a recorded dataset.
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// Measure accuracy against a reference (trajectories).
    #[command(subcommand)]
    Eval(eval::EvalCommand),
    /// The voxel-planes paper's study: runtime against points and
    /// cross-validation error against size, voxel planes vs TSDF + marching cubes.
    Study(study::StudyArgs),
    /// Run the mapping service: sensor clients stream depth, each maps a session.
    Serve(serve::ServeArgs),
    /// Stream a recorded dataset or a simulated scene to a mapping server.
    Stream(stream::StreamArgs),
    /// Follow a session's view without a browser and print what arrived (JSON).
    Watch(watch::WatchArgs),
    /// What a map store holds: frames, blocks, bytes, last checkpoint, settings (JSON).
    Info(info::InfoArgs),
    /// Simplify a mesh file by quadric edge collapse.
    Simplify(simplify::SimplifyArgs),
    /// Write a mesh as game-engine assets: chunked GLB, OBJ or PLY.
    Export(export::ExportArgs),
    /// Map a site with several machines over NATS JetStream: workers,
    /// the site's map, its status, a replay of its stream.
    #[command(subcommand)]
    Cluster(cluster::ClusterCommand),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Simulate(args) => simulate::run(&args, cli.quiet).map(|_| ()),
        Command::Demo(args) => demo::run(&args, cli.quiet),
        Command::Reconstruct(args) => reconstruct::run(&args, cli.quiet),
        Command::Bench(command) => bench::run(&command),
        Command::Eval(command) => eval::run(&command),
        Command::Study(args) => study::run(&args, cli.quiet),
        Command::Serve(args) => serve::run(&args),
        Command::Stream(args) => stream::run(&args, cli.quiet),
        Command::Watch(args) => watch::run(&args),
        Command::Info(args) => info::run(&args),
        Command::Simplify(args) => simplify::run(&args, cli.quiet),
        Command::Export(args) => export::run(&args, cli.quiet),
        Command::Cluster(command) => cluster::run(&command, cli.quiet),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", name_flags(&format!("{e:#}")));
            ExitCode::FAILURE
        }
    }
}

/// Library fields and the flags that set them: the library names what it
/// rejects by field; a person typed a flag.
const FLAGS: &[(&str, &str)] = &[
    ("voxel", "--voxel"),
    ("truncation", "--trunc"),
    ("active radius", "--active-radius"),
    ("stride", "--stride"),
    ("depth_min", "--depth-min"),
    ("depth_max", "--depth-max"),
    ("depth_scale", "--depth-scale"),
    ("min_weight", "--min-weight"),
    ("frames", "--frames"),
    ("intrinsics", "--intrinsics"),
    ("ratio", "--ratio"),
    ("target_triangles", "--target-triangles"),
    ("max_error", "--max-error"),
    ("align_floor", "--align-floor"),
    ("chunk_vertices", "--chunk-vertices"),
    ("path", "--path"),
    ("noise", "--noise"),
    ("format", "--format"),
    ("scale", "--scale"),
    ("epsilon", "--epsilon"),
    ("grid.voxel", "--plane-voxel"),
    ("grid.cell", "--plane-cell"),
];

/// An error message with the library's "invalid FIELD:" shown as the flag
/// that sets the field.
fn name_flags(message: &str) -> String {
    let mut message = message.to_string();
    for (field, flag) in FLAGS {
        message = message.replace(&format!("invalid {field}:"), &format!("invalid {flag}:"));
    }
    message
}
