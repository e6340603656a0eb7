//! What a stage outside the solvers (the contact response) may change in a body, saved before
//! its first change and put back when the stage fails, so a failed stage leaves every body as
//! it was before it.

use super::{Level, LeveledModel};
use crate::Vec3;
use crate::state::{NodalModel, Nodes};

/// A body's state at its current level as the contact response may change it: positions,
/// velocities and pending external forces of the level's nodes (the precise body's, or the
/// cage's vertices' and the cage's contact dent), and the shadow simulation's pending
/// forces. Its buffers keep their room
/// between uses, so saving does not allocate after the first time.
#[derive(Debug, Default, Clone)]
pub struct LevelSnapshot {
    level: Option<Level>,
    asleep: bool,
    x: Vec<Vec3>,
    v: Vec<Vec3>,
    f: Vec<Vec3>,
    shadow_f: Vec<Vec3>,
    /// The cage's dent (empty: none).
    dent: Vec<Vec3>,
}

fn copy(dst: &mut Vec<Vec3>, src: &[Vec3]) {
    dst.clear();
    dst.extend_from_slice(src);
}

fn finite(v: &Vec3) -> bool {
    v.iter().all(|c| c.is_finite())
}

impl LevelSnapshot {
    /// Whether it holds a saved state (cleared by [`LevelSnapshot::clear`]).
    pub fn is_saved(&self) -> bool {
        self.level.is_some()
    }

    /// Forgets the saved state (keeps the room).
    pub fn clear(&mut self) {
        self.level = None;
    }
}

impl LeveledModel {
    fn level_nodes(&self) -> &Nodes {
        match self.level {
            Level::Precise => self.precise.model().nodes(),
            Level::Cage => self.cage.msd().nodes(),
        }
    }

    fn level_nodes_mut(&mut self) -> &mut Nodes {
        match self.level {
            Level::Precise => self.precise.model_mut().nodes_mut(),
            Level::Cage => self.cage.msd_mut().nodes_mut(),
        }
    }

    /// Saves into `s` what a stage may change at the current level (see [`LevelSnapshot`]).
    pub fn save_level_state(&self, s: &mut LevelSnapshot) {
        let n = self.level_nodes();
        copy(&mut s.x, &n.x);
        copy(&mut s.v, &n.v);
        copy(&mut s.f, &n.f_ext);
        match &self.shadow {
            Some(sh) => copy(&mut s.shadow_f, &sh.model().nodes().f_ext),
            None => s.shadow_f.clear(),
        }
        match (self.level, self.cage.dent()) {
            (Level::Cage, Some(d)) => copy(&mut s.dent, d),
            _ => s.dent.clear(),
        }
        s.asleep = self.asleep;
        s.level = Some(self.level);
    }

    /// Puts back the state `s` saved. Returns `false`, changing nothing, when `s` holds no
    /// state or one of another level (the level changed since: nothing of it to restore).
    pub fn restore_level_state(&mut self, s: &LevelSnapshot) -> bool {
        if s.level != Some(self.level) {
            return false;
        }
        let n = self.level_nodes_mut();
        n.x.copy_from_slice(&s.x);
        n.v.copy_from_slice(&s.v);
        n.f_ext.copy_from_slice(&s.f);
        if let Some(sh) = &mut self.shadow
            && sh.model().nodes().f_ext.len() == s.shadow_f.len()
        {
            sh.model_mut()
                .nodes_mut()
                .f_ext
                .copy_from_slice(&s.shadow_f);
        }
        self.asleep = s.asleep;
        if self.level == Level::Cage {
            self.cage.clear_dent();
            if !s.dent.is_empty() {
                // Saved from this cage: the length fits and the values are finite.
                let _ = self.cage.add_dent(&s.dent);
            }
            // The points follow the restored cage (a failure is the caller's to find: it
            // checks the state it puts back).
            let _ = self.cage.update_points();
        }
        true
    }

    /// The first non-finite position, velocity or pending force of the current level's nodes,
    /// as `(what, node)` (a cage vertex at the cage level).
    pub fn first_non_finite_level_state(&self) -> Option<(&'static str, usize)> {
        let n = self.level_nodes();
        n.first_non_finite_input().or_else(|| {
            let sh = self.shadow.as_ref()?;
            sh.model()
                .nodes()
                .f_ext
                .iter()
                .position(|f| !finite(f))
                .map(|i| ("shadow force", i))
        })
    }
}
