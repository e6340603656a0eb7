//! Haptic tools (feature `haptics`): a [`HapticTool`] on a [`SoftTool`] entity runs the core's
//! 1 kHz haptic thread ([`soft_tissue_core::haptics`]) with a device of your choice. At the
//! start of every physics step the tool is put where the thread's tool proxy is and its
//! buttons set grab (first button; with a blade it cuts instead) and cautery (second); after
//! the step the tissue's local
//! contact model is handed back to the thread, which renders the force between steps, and
//! with it a cutting blade's cut model (the thread renders the cutting resistance as a
//! friction across the edge, breakaway at the toughness times the edge's length in tissue:
//! [`soft_tissue_core::haptics::cutting`]).
//! Removing the component (or despawning the entity) stops the thread and leaves the device
//! with zero force. The thread asks for real-time scheduling ([`HapticConfig::priority`]);
//! [`HapticTool::priority`] says what it got, and the physics (Bevy's threads) stays at normal
//! priority.
//!
//! ```no_run
//! use bevy::prelude::*;
//! use bevy_soft_tissue::haptics::HapticTool;
//! use bevy_soft_tissue::core::haptics::{HapticConfig, VirtualDevice};
//! use bevy_soft_tissue::prelude::*;
//!
//! fn setup(mut commands: Commands) {
//!     let (device, handle) = VirtualDevice::new(Default::default(), 8.0);
//!     let haptic = HapticTool::start(Box::new(device), HapticConfig::default(), 10.0).unwrap();
//!     commands.spawn((SoftTool::sphere(0.05), haptic));
//!     // Move `handle` (e.g. from the mouse) with `handle.set(position, buttons)`.
//! }
//! ```

use std::sync::Arc;

use bevy::prelude::*;
use soft_tissue_core::haptics::{
    ContactModel, CutModel, HapticConfig, HapticDevice, HapticError, HapticShared, HapticThread,
    PriorityOutcome, ToolSample, contact_model, cut_model,
};

use crate::components::{SoftTool, ToolState};
use crate::physics::{SoftTissueContacts, SoftTissueSchedule, SoftTissueStatus, SoftTissueSystems};
use soft_tissue_core::contact::ToolShape;

pub use soft_tissue_core::haptics::{CAUTERY_BUTTON, CUT_BUTTON, GRAB_BUTTON};

/// Drives [`HapticTool`] entities in the simulation's schedule ([`SoftTissueSchedule`]).
#[derive(Default)]
pub struct SoftTissueHapticsPlugin;

impl Plugin for SoftTissueHapticsPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(
            SoftTissueSchedule,
            (
                drive_tools.in_set(SoftTissueSystems::First),
                publish_models.in_set(SoftTissueSystems::Last),
            ),
        );
    }
}

/// A tool driven by a haptic device through the haptic thread (see the module docs).
#[derive(Component)]
pub struct HapticTool {
    thread: HapticThread,
    /// Electrocautery power while the second button is held, W.
    pub cautery_watts: f64,
    /// Tissue stiffness the contact model starts from (scene units; it adapts to the
    /// measured force). Default: the coupling stiffness.
    pub nominal_stiffness: f64,
    /// Stiffness of the cut's bristle ([`HapticTool::set_cut_stiffness`]).
    cut_stiffness: f64,
    model: ContactModel,
    cut: CutModel,
    last: ToolSample,
    /// The last warning given about the models handed to the thread: each is given once,
    /// until a handover works again.
    warned: Option<String>,
}

impl HapticTool {
    /// Starts the haptic thread with `device`.
    pub fn start(
        device: Box<dyn HapticDevice>,
        config: HapticConfig,
        cautery_watts: f64,
    ) -> Result<Self, HapticError> {
        let thread = HapticThread::spawn(device, config)?;
        let priority = thread.priority();
        if priority.refused.is_some() {
            warn!("haptic thread priority: {priority}");
        } else {
            info!("haptic thread priority: {priority}");
        }
        let last = thread.shared().tool();
        Ok(HapticTool {
            thread,
            cautery_watts,
            nominal_stiffness: config.coupling.stiffness,
            cut_stiffness: CutModel::STIFFNESS_PER_COUPLING * config.coupling.stiffness,
            model: ContactModel::NONE,
            cut: CutModel::NONE,
            last,
            warned: None,
        })
    }

    /// Stiffness of the cut's bristle (scene units): a cutting blade moves
    /// `breakaway / cut_stiffness` across its edge before it slips on. Default:
    /// [`CutModel::STIFFNESS_PER_COUPLING`] times the coupling stiffness.
    pub fn cut_stiffness(&self) -> f64 {
        self.cut_stiffness
    }

    /// Sets the stiffness of the cut's bristle (scene units), used from the next physics
    /// step. One that is not finite and > 0 is refused ([`HapticError::BadConfig`] naming
    /// `cut_stiffness` and the value), and the stiffness is left as it was.
    pub fn set_cut_stiffness(&mut self, stiffness: f64) -> Result<(), HapticError> {
        if !(stiffness.is_finite() && stiffness > 0.0) {
            return Err(HapticError::BadConfig {
                what: "cut_stiffness",
                value: stiffness,
                why: "finite and > 0",
            });
        }
        self.cut_stiffness = stiffness;
        Ok(())
    }

    /// Warns of `text` unless it was the last warning given.
    fn warn_once(&mut self, entity: Entity, text: String) {
        if self.warned.as_ref() != Some(&text) {
            warn!("haptic tool {entity}: {text}");
            self.warned = Some(text);
        }
    }

    /// The tool as of the last physics step (proxy pose, device pose, force, buttons).
    pub fn sample(&self) -> &ToolSample {
        &self.last
    }

    /// The contact model handed to the thread at the last step.
    pub fn model(&self) -> &ContactModel {
        &self.model
    }

    /// The cut model handed to the thread at the last step ([`CutModel::NONE`] unless the
    /// tool is a blade cutting tissue with a toughness).
    pub fn cut(&self) -> &CutModel {
        &self.cut
    }

    /// The scheduling the haptic thread asked for and got (policy and priority, or why the
    /// request was refused).
    pub fn priority(&self) -> &PriorityOutcome {
        self.thread.priority()
    }

    /// The state shared with the thread (live tool sample, tick count).
    pub fn shared(&self) -> &Arc<HapticShared> {
        self.thread.shared()
    }
}

fn drive_tools(mut tools: Query<(&mut HapticTool, &mut Transform, &mut SoftTool)>) {
    for (mut haptic, mut pose, mut tool) in &mut tools {
        let s = haptic.thread.shared().tool();
        haptic.last = s;
        let p = Vec3::new(
            s.position.x as f32,
            s.position.y as f32,
            s.position.z as f32,
        );
        if p.is_finite() && pose.translation != p {
            pose.translation = p;
        }
        // The first button grabs, or with a blade cuts.
        let pressed = s.buttons & GRAB_BUTTON != 0;
        let blade = matches!(tool.shape, ToolShape::Blade { .. });
        let (grab, cut) = (
            pressed && !blade,
            blade && (pressed || s.buttons & CUT_BUTTON != 0),
        );
        if tool.grab != grab {
            tool.grab = grab;
        }
        if tool.cut != cut {
            tool.cut = cut;
        }
        let watts = if s.buttons & CAUTERY_BUTTON != 0 {
            haptic.cautery_watts
        } else {
            0.0
        };
        if tool.cautery_watts != watts {
            tool.cautery_watts = watts;
        }
    }
}

fn publish_models(
    mut haptics: Query<(Entity, &mut HapticTool)>,
    tools: Query<(Entity, &ToolState)>,
    contacts: Res<SoftTissueContacts>,
    status: Res<SoftTissueStatus>,
) {
    if haptics.is_empty() {
        return;
    }
    for (entity, mut haptic) in &mut haptics {
        let Some(index) = (0..)
            .map_while(|i| contacts.tool_entity(i))
            .position(|e| e == entity)
        else {
            continue;
        };
        let Ok((_, state)) = tools.get(entity) else {
            continue;
        };
        let model = contact_model(
            &state.tool,
            index as u32,
            contacts.core(),
            &haptic.model,
            haptic.nominal_stiffness,
            status.steps,
        );
        // A cut model that cannot be made (the blade's strength not finite) is dropped with
        // a warning, given once: the contact still goes over.
        let (cut, cut_error) = match cut_model(&state.tool, haptic.cut_stiffness) {
            Ok(cut) => (cut, None),
            Err(e) => (CutModel::NONE, Some(format!("haptic cut model: {e}"))),
        };
        haptic.model = model;
        haptic.cut = cut;
        let published = haptic.thread.shared().publish(&model, &cut);
        match (cut_error, published) {
            (_, Err(e)) => haptic.warn_once(entity, format!("haptic models: {e}")),
            (Some(text), Ok(())) => haptic.warn_once(entity, text),
            (None, Ok(())) => haptic.warned = None,
        }
    }
}
