//! The examples' command-line options.

use std::path::PathBuf;

use bevy::prelude::*;

/// Command-line options of the examples.
#[derive(Resource, Clone, Debug, Default)]
pub struct ExampleOptions {
    /// Save a PNG here after `frames` frames, then exit.
    pub screenshot: Option<PathBuf>,
    /// Frames to render before the screenshot.
    pub frames: u32,
    /// Rounds of subdivision of the drawn surface (0: the simulation surface).
    pub smooth: u8,
    /// With `--screenshot`: the mouse drives the tool instead of the built-in script.
    pub mouse: bool,
    /// `--scene FILE` (relative to the assets folder, or a path): a scene RON file shown
    /// instead of the example's own; `--large` is `scenes/organs-large.scene.ron`.
    pub scene: Option<PathBuf>,
    /// `--surface FILE` (relative to the assets folder): a closed triangle surface (.obj,
    /// .stl, .ply, .gltf, .glb) meshed on load and added as a body beside the scene, drawn with the
    /// surface itself.
    pub surface: Option<String>,
    /// `--close-up`: the camera close above where the scripted tool works (a burn, a cut).
    pub close_up: bool,
}

impl ExampleOptions {
    /// Parses `--screenshot FILE --frames N --smooth L --mouse --scene FILE --large
    /// --surface FILE --close-up`.
    pub fn from_args() -> Result<Self, String> {
        let mut o = ExampleOptions {
            screenshot: None,
            frames: 240,
            smooth: 2,
            mouse: false,
            scene: None,
            surface: None,
            close_up: false,
        };
        let mut args = std::env::args().skip(1);
        while let Some(a) = args.next() {
            match a.as_str() {
                "--screenshot" => {
                    o.screenshot = Some(args.next().ok_or("--screenshot needs a file")?.into())
                }
                "--frames" => {
                    o.frames = args
                        .next()
                        .ok_or("--frames needs a number")?
                        .parse()
                        .map_err(|e| format!("--frames: {e}"))?
                }
                "--mouse" => o.mouse = true,
                "--close-up" => o.close_up = true,
                "--scene" => o.scene = Some(args.next().ok_or("--scene needs a file")?.into()),
                "--large" => o.scene = Some("scenes/organs-large.scene.ron".into()),
                "--surface" => o.surface = Some(args.next().ok_or("--surface needs a file")?),
                "--smooth" => {
                    o.smooth = args
                        .next()
                        .ok_or("--smooth needs a number")?
                        .parse()
                        .map_err(|e| format!("--smooth: {e}"))?;
                    if o.smooth > 4 {
                        return Err(format!("--smooth {} is more than 4", o.smooth));
                    }
                }
                other => {
                    return Err(format!(
                        "unknown option {other} (--screenshot FILE --frames N --smooth L --mouse \
                         --scene FILE --large --surface FILE --close-up)"
                    ));
                }
            }
        }
        Ok(o)
    }
}
