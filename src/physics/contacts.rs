//! Contacts of the last step, by entity.

use super::*;
use soft_tissue_core::contact::Counterpart;

/// Contacts of the last step, by entity ([`SoftTissueContacts::iter`]).
#[derive(Resource, Default)]
pub struct SoftTissueContacts {
    /// The core's contact state (bodies and tools by their index in `bodies` / `tools`).
    pub(crate) state: ContactState,
    /// The body entities in the order the core's stage functions see them.
    pub(crate) bodies: Vec<Entity>,
    /// The tool entities in that order.
    pub(crate) tools: Vec<Entity>,
    /// The contacts by pair.
    pairs: Vec<SoftContact>,
}

/// What a body touches.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ContactPartner {
    /// A tool entity ([`SoftTool`]).
    Tool(Entity),
    /// Another body's entity ([`SoftBody`]).
    Body(Entity),
    /// A static obstacle's entity ([`SoftObstacle`]).
    Obstacle(Entity),
}

/// The contacts between a body and one partner this step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SoftContact {
    /// The body (for two bodies: the one whose vertices were tested).
    pub body: Entity,
    /// What it touches.
    pub partner: ContactPartner,
    /// Contact points of the step's contact solve (with a force, or penetrating).
    pub points: u32,
    /// Deepest penetration after the step, scene units (0 when none penetrates).
    pub max_depth: f64,
    /// The force of the partner on the body, summed over the points (scene units).
    pub force: Vec3,
}

impl SoftTissueContacts {
    /// Every body-partner pair in contact this step.
    pub fn iter(&self) -> impl Iterator<Item = &SoftContact> {
        self.pairs.iter()
    }

    /// The contacts `entity` (a body or a tool) takes part in.
    pub fn involving(&self, entity: Entity) -> impl Iterator<Item = &SoftContact> {
        self.pairs.iter().filter(move |c| {
            c.body == entity
                || matches!(c.partner, ContactPartner::Tool(t) | ContactPartner::Body(t) | ContactPartner::Obstacle(t) if t == entity)
        })
    }

    /// The core's contact state, for drawing or analysis; map its indices with
    /// [`SoftTissueContacts::body_entity`] and [`SoftTissueContacts::tool_entity`].
    pub fn core(&self) -> &ContactState {
        &self.state
    }

    /// The entity of the core's body index `index`.
    pub fn body_entity(&self, index: u32) -> Option<Entity> {
        self.bodies.get(index as usize).copied()
    }

    /// The entity of the core's tool index `index`.
    pub fn tool_entity(&self, index: u32) -> Option<Entity> {
        self.tools.get(index as usize).copied()
    }

    /// The pairs gathered from the core's contact solve (`obstacles`: the obstacle entities
    /// in the core's order).
    pub(super) fn gather(&mut self, obstacles: &[Entity]) {
        self.pairs.clear();
        for r in self.state.solved_rows() {
            let penetration = if r.is_contact() {
                (-r.gap).max(0.0)
            } else {
                0.0
            };
            if r.force == soft_tissue_core::Vec3::zeros() && penetration == 0.0 {
                continue;
            }
            let body = self.bodies.get(r.a.body as usize).copied();
            let partner = match r.other {
                Counterpart::Tool { tool, .. } => self
                    .tools
                    .get(tool as usize)
                    .copied()
                    .map(ContactPartner::Tool),
                Counterpart::Body(p) => self
                    .bodies
                    .get(p.body as usize)
                    .copied()
                    .map(ContactPartner::Body),
                Counterpart::Obstacle(i) => obstacles
                    .get(i as usize)
                    .copied()
                    .map(ContactPartner::Obstacle),
            };
            let (Some(body), Some(partner)) = (body, partner) else {
                continue;
            };
            let force = to_bevy(&r.world_force());
            match self
                .pairs
                .iter_mut()
                .find(|c| c.body == body && c.partner == partner)
            {
                Some(c) => {
                    c.points += 1;
                    c.max_depth = c.max_depth.max(penetration);
                    c.force += force;
                }
                None => self.pairs.push(SoftContact {
                    body,
                    partner,
                    points: 1,
                    max_depth: penetration,
                    force,
                }),
            }
        }
    }

    pub(super) fn clear(&mut self) {
        self.state.clear();
        self.pairs.clear();
    }
}
