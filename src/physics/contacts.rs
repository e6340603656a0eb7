//! Contacts of the last step, by entity.

use super::*;

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
}

/// The contacts between a body and one partner this step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SoftContact {
    /// The body (for two bodies: the one whose vertices were tested).
    pub body: Entity,
    /// What it touches.
    pub partner: ContactPartner,
    /// Contact points (tool: surface triangles under the tip; bodies: vertex-triangle
    /// pairs).
    pub points: u32,
    /// Deepest penetration at detection, scene units.
    pub max_depth: f64,
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
                || matches!(c.partner, ContactPartner::Tool(t) | ContactPartner::Body(t) if t == entity)
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

    /// The pairs gathered from the core's state.
    pub(super) fn gather(&mut self) {
        self.pairs.clear();
        let mut add = |body: Option<Entity>, partner: Option<ContactPartner>, depth: f64| {
            let (Some(body), Some(partner)) = (body, partner) else {
                return;
            };
            match self
                .pairs
                .iter_mut()
                .find(|c| c.body == body && c.partner == partner)
            {
                Some(c) => {
                    c.points += 1;
                    c.max_depth = c.max_depth.max(depth);
                }
                None => self.pairs.push(SoftContact {
                    body,
                    partner,
                    points: 1,
                    max_depth: depth,
                }),
            }
        };
        for t in &self.state.tool_contacts {
            add(
                self.bodies.get(t.body as usize).copied(),
                self.tools
                    .get(t.tool as usize)
                    .copied()
                    .map(ContactPartner::Tool),
                t.depth,
            );
        }
        for b in &self.state.body_contacts {
            add(
                self.bodies.get(b.a as usize).copied(),
                self.bodies
                    .get(b.b as usize)
                    .copied()
                    .map(ContactPartner::Body),
                b.depth,
            );
        }
    }

    pub(super) fn clear(&mut self) {
        self.state.clear();
        self.pairs.clear();
    }
}
