//! `soft-tissue scene`: the paper's scenes written as RON files.

use std::path::{Path, PathBuf};

use clap::Subcommand;
use soft_tissue_core::scenario::{PreciseMethod, Scene};

use crate::Res;

#[derive(Subcommand)]
pub(crate) enum SceneCommand {
    /// Write cylinders.scene.ron and organs.scene.ron (the paper's parameters) into DIR.
    Export {
        /// Output folder (created if missing).
        #[arg(long)]
        out: PathBuf,
    },
}

/// Runs a `scene` command.
pub(crate) fn run(command: SceneCommand) -> Res {
    match command {
        SceneCommand::Export { out } => export_scenes(&out),
    }
}

fn export_scenes(out: &Path) -> Res {
    std::fs::create_dir_all(out)?;
    let scenes = [
        Scene::paper_cylinders(PreciseMethod::LinearFem, PreciseMethod::LinearFem),
        Scene::paper_organs(),
        Scene::large_organs(),
    ];
    for s in scenes {
        let path = out.join(format!("{}.scene.ron", s.name));
        std::fs::write(&path, s.to_ron())?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
