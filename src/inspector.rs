//! The inspector (feature `inspector`, bevy_egui): every body (by its `Name`, else its mesh's
//! file name: see [`body_label`]) with its level, precise method
//! (switchable), Young's modulus (editable: the body's [`TissueMaterial`]), step time, switches, last jump, temperature range, burnt volumes (coagulated / charred / vaporized, mm^3), shadow error and
//! unconverged solves, cut area and pieces; the simulation's rate, the last step's time and the median, 99th
//! percentile and largest of the whole step and of each stage over the last steps, the error
//! of a failed step, pause / single step / reset, the simulation's speed; and a live plot of each body's step time
//! over the last seconds, like the paper's figures.

use std::collections::VecDeque;

use bevy::prelude::*;
use bevy_egui::{EguiContexts, EguiPlugin, EguiPrimaryContextPass, egui};
use egui_plot::{Legend, Line, Plot, PlotPoints};

use crate::assets::body_label;
use crate::components::*;
use crate::core::contact::ToolShape;
use crate::core::timing::StageTimes;
use crate::physics::{ResetSimulation, SoftPhysics, SoftPhysicsTime, SoftTissueStatus};

/// Adds the panel (and `EguiPlugin` when the app has none).
pub struct SoftTissueInspectorPlugin;

impl Plugin for SoftTissueInspectorPlugin {
    fn build(&self, app: &mut App) {
        if !app.is_plugin_added::<EguiPlugin>() {
            app.add_plugins(EguiPlugin::default());
        }
        app.init_resource::<StepHistory>()
            .add_systems(Update, record_history)
            .add_systems(EguiPrimaryContextPass, inspector_panel);
    }
}

/// Per-body step times of the last steps, for the plot.
#[derive(Resource, Default)]
pub struct StepHistory {
    last_step: u64,
    /// (entity, name, [(step, microseconds)]).
    series: Vec<(Entity, String, VecDeque<[f64; 2]>)>,
}

/// Steps kept in the plot.
const HISTORY: usize = 500;

fn record_history(
    status: Res<SoftTissueStatus>,
    server: Res<AssetServer>,
    bodies: Query<(
        Entity,
        Option<&Name>,
        Option<&SoftBody>,
        &SoftBodyDiagnostics,
    )>,
    mut history: ResMut<StepHistory>,
) {
    if status.steps == history.last_step {
        return;
    }
    if status.steps < history.last_step {
        history.series.clear();
    }
    history.last_step = status.steps;
    let step = status.steps as f64;
    for (e, name, body, d) in &bodies {
        let i = match history.series.iter().position(|s| s.0 == e) {
            Some(i) => i,
            None => {
                let n = body_label(e, name, body, &server);
                history
                    .series
                    .push((e, n, VecDeque::with_capacity(HISTORY)));
                history.series.len() - 1
            }
        };
        let s = &mut history.series[i].2;
        if s.len() == HISTORY {
            s.pop_front();
        }
        s.push_back([step, d.step_us]);
    }
}

#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn inspector_panel(
    mut contexts: EguiContexts,
    mut status: ResMut<SoftTissueStatus>,
    mut clock: ResMut<Time<SoftPhysics>>,
    history: Res<StepHistory>,
    server: Res<AssetServer>,
    mut bodies: Query<(
        Entity,
        Option<&Name>,
        &mut SoftBody,
        &mut TissueMaterial,
        &PrecisionLevel,
        &SoftBodyDiagnostics,
        Option<&Temperature>,
    )>,
    pieces: Query<&CutPiece>,
    mut tools: Query<(Entity, Option<&Name>, &mut SoftTool, &ToolReaction)>,
    mut reset: MessageWriter<ResetSimulation>,
) -> Result {
    let ctx = contexts.ctx_mut()?;
    egui::Window::new("Soft tissue")
        .default_pos([10.0, 10.0])
        .default_width(560.0)
        .show(ctx, |ui| {
            let t = status.times;
            let dt = clock.timestep().as_secs_f64();
            ui.label(format!(
                "physics {:.0} Hz (dt {} s), step {}: {:.0} us, simulated {:.2} s",
                1.0 / dt,
                dt,
                status.steps,
                t.total_us(),
                clock.elapsed_secs_f64(),
            ));
            let mut speed = clock.relative_speed();
            if ui
                .add(egui::Slider::new(&mut speed, 0.0..=2.0).text("speed"))
                .changed()
            {
                // The slider's range is a valid speed.
                let _ = clock.set_relative_speed(speed);
            }
            // Real time is decided by the worst step: the last one, and the median, 99th
            // percentile and largest of the last steps, whole and per stage.
            let stats = status.recent.summary();
            egui::Grid::new("stages").striped(true).show(ui, |ui| {
                for h in ["us", "last", "median", "p99", "max"] {
                    ui.strong(h);
                }
                ui.end_row();
                let last = t.values();
                let rows = std::iter::once(("step", t.total_us(), &stats.step)).chain(
                    StageTimes::NAMES
                        .iter()
                        .zip(last)
                        .zip(&stats.stages)
                        .map(|((n, l), s)| (*n, l, s)),
                );
                for (name, last, s) in rows {
                    ui.label(name);
                    for v in [last, s.median_us, s.p99_us, s.max_us] {
                        ui.label(format!("{v:.0}"));
                    }
                    ui.end_row();
                }
            });
            ui.label(format!("over the last {} steps", stats.step.count));
            ui.horizontal(|ui| {
                let label = if clock.is_paused() { "Resume" } else { "Pause" };
                if ui.button(label).clicked() {
                    if clock.is_paused() {
                        // Resuming after a failed step carries on from the state it left.
                        clock.unpause();
                        status.error = None;
                    } else {
                        clock.pause();
                    }
                }
                if ui.button("Step").clicked() {
                    clock.pause();
                    clock.step_once();
                }
                if ui.button("Reset").clicked() {
                    reset.write(ResetSimulation);
                }
            });
            if let Some(e) = &status.error {
                ui.colored_label(egui::Color32::LIGHT_RED, e.to_string());
            }
            // Wide tables scroll sideways: the window stays clear of the scene.
            egui::ScrollArea::horizontal()
                .id_salt("bodies-scroll")
                .max_width(600.0)
                .show(ui, |ui| {
                    egui::Grid::new("bodies").striped(true).show(ui, |ui| {
                        for h in [
                            "body",
                            "level",
                            "method",
                            "E",
                            "mu",
                            "step us",
                            "contacts",
                            "pen. %",
                            "switches",
                            "jump %",
                            "C",
                            "burnt mm3",
                            "cage %",
                            "unconv.",
                            "cut area",
                            "pieces",
                        ] {
                            ui.strong(h);
                        }
                        ui.end_row();
                        let mut rows: Vec<_> = bodies.iter_mut().collect();
                        rows.sort_by_key(|r| r.0);
                        for (e, name, mut body, mut material, level, diag, temp) in rows {
                            ui.label(body_label(e, name, Some(&*body), &server));
                            let (text, colour) = match level.level {
                                Level::Cage => ("cage", egui::Color32::from_rgb(90, 170, 255)),
                                Level::Precise => {
                                    ("precise", egui::Color32::from_rgb(255, 150, 60))
                                }
                            };
                            ui.colored_label(colour, text);
                            let mut method = body.method;
                            egui::ComboBox::from_id_salt(("method", e))
                                .selected_text(method.name())
                                .show_ui(ui, |ui| {
                                    for m in PreciseMethod::ALL {
                                        ui.selectable_value(&mut method, m, m.name());
                                    }
                                });
                            if method != body.method {
                                body.method = method;
                            }
                            // Young's modulus: the material is the body's data, edited in place.
                            let mut young = material.fem.young_modulus;
                            if ui
                                .add(
                                    egui::DragValue::new(&mut young)
                                        .speed(1.0)
                                        .range(1e-3..=1e9),
                                )
                                .changed()
                            {
                                material.fem.young_modulus = young;
                            }
                            // Friction (static; the kinetic one kept at most the static).
                            let mut mu = material.friction.static_coefficient;
                            if ui
                                .add(egui::DragValue::new(&mut mu).speed(0.01).range(0.0..=2.0))
                                .changed()
                            {
                                let f = &mut material.friction;
                                f.static_coefficient = mu;
                                f.kinetic_coefficient = f.kinetic_coefficient.min(mu);
                            }
                            ui.label(format!("{:.0}", diag.step_us));
                            ui.label(format!("{}", diag.contacts));
                            ui.label(format!("{:.4}", 100.0 * diag.penetration_ratio));
                            ui.label(format!("{}", level.switches));
                            ui.label(
                                level
                                    .last_jump_ratio
                                    .map_or("-".into(), |r| format!("{:.3}", 100.0 * r)),
                            );
                            ui.label(
                                temp.map_or("-".into(), |t| format!("{:.1}..{:.1}", t.min, t.max)),
                            );
                            // Burnt at the electrodes' scale: coagulated / charred / vaporized.
                            ui.label(
                                temp.filter(|t| t.coagulated_mm3 > 0.0 || t.charred_mm3 > 0.0)
                                    .map_or("-".into(), |t| {
                                        format!(
                                            "{:.1}/{:.1}/{:.1}",
                                            t.coagulated_mm3, t.charred_mm3, t.vaporized_mm3
                                        )
                                    }),
                            );
                            ui.label(
                                diag.shadow_error_ratio
                                    .map_or("-".into(), |r| format!("{:.2}", 100.0 * r)),
                            );
                            // Solves stopped at their cap: shown in red, they are inexact steps.
                            if diag.unconverged_solves > 0 {
                                ui.colored_label(
                                    egui::Color32::LIGHT_RED,
                                    format!("{}", diag.unconverged_solves),
                                );
                            } else {
                                ui.label("0");
                            }
                            // Cuts: the area of this body's cut sides, and the pieces of the body it
                            // came from (itself and those cut loose from it).
                            if diag.cut_faces > 0 {
                                ui.label(format!("{:.3e}", diag.cut_area));
                            } else {
                                ui.label("-");
                            }
                            // The uncut body: follow the pieces back to it.
                            let root = |mut x: Entity| {
                                while let Ok(p) = pieces.get(x) {
                                    x = p.from;
                                }
                                x
                            };
                            let from = root(e);
                            let count = pieces.iter().filter(|p| root(p.from) == from).count();
                            ui.label(if count > 0 {
                                format!("{}", count + 1)
                            } else {
                                "-".into()
                            });
                            ui.end_row();
                        }
                    });
                });
            // Tools: the contact force the step balanced, and the jaws of a grasper.
            egui::Grid::new("tools").striped(true).show(ui, |ui| {
                for h in ["tool", "force", "|F|", "contacts", "grips", "jaws", "mu"] {
                    ui.strong(h);
                }
                ui.end_row();
                let mut rows: Vec<_> = tools.iter_mut().collect();
                rows.sort_by_key(|r| r.0);
                for (e, name, mut tool, reaction) in rows {
                    ui.label(name.map_or_else(|| format!("{e}"), |n| n.as_str().to_owned()));
                    let f = reaction.force;
                    ui.label(format!("({:.2}, {:.2}, {:.2})", f.x, f.y, f.z));
                    ui.label(format!("{:.3}", f.length()));
                    ui.label(format!("{}", reaction.contacts));
                    ui.label(format!("{}", reaction.grips));
                    if let ToolShape::Grasper { max_opening, .. } = tool.shape {
                        let mut jaws = tool.jaws;
                        if ui
                            .add(
                                egui::Slider::new(&mut jaws, 0.0..=max_opening).text(format!(
                                    "{:.3} now, squeeze {:.2} / {:.2}",
                                    reaction.opening,
                                    reaction.jaw_forces[0],
                                    reaction.jaw_forces[1]
                                )),
                            )
                            .changed()
                        {
                            tool.jaws = jaws;
                        }
                    } else {
                        ui.label("-");
                    }
                    let mut mu = tool.friction.static_coefficient;
                    if ui
                        .add(egui::DragValue::new(&mut mu).speed(0.01).range(0.0..=2.0))
                        .changed()
                    {
                        tool.friction.static_coefficient = mu;
                        tool.friction.kinetic_coefficient =
                            tool.friction.kinetic_coefficient.min(mu);
                    }
                    ui.end_row();
                }
            });
            Plot::new("step-times")
                .height(180.0)
                .legend(Legend::default())
                .show(ui, |plot| {
                    for (_, name, s) in &history.series {
                        let points: PlotPoints = s.iter().copied().collect();
                        plot.line(Line::new(name.clone(), points));
                    }
                });
            ui.label("step time per body, us, over the last steps");
        });
    Ok(())
}
