//! [`SoftTissueWorld`]: bodies, tools and the stages run in order, one fixed step at a time.

use super::*;

/// Bodies, tools and the stages (see the module docs).
#[derive(Debug)]
pub struct SoftTissueWorld {
    config: WorldConfig,
    bodies: Vec<WorldBody>,
    tools: Vec<Tool>,
    /// Blades' pulls on the bodies of the step (kept to reuse its room).
    cut_loads: Vec<super::cut_force::CutLoad>,
    obstacles: Vec<Obstacle>,
    contacts: ContactState,
    steps: u64,
    accumulator: f64,
    times: StageTimes,
    threads: crate::parallel::Threads,
    /// The error of the step that failed, until `resume` or `reset`.
    halted: Option<String>,
    /// How blades cut.
    cut_options: crate::mesh::cut::CutOptions,
    /// Bodies as they were before their first cut, by index (`reset` puts them back).
    uncut: Vec<(usize, WorldBody)>,
    /// Each tool's incision while it cuts.
    incisions: Vec<Option<super::cut::Incision>>,
    /// Cuts being prepared on threads of their own, in the order they began.
    in_flight: Vec<InFlight>,
}

/// A cut being prepared ([`crate::mesh::cut::CutOptions::background_steps`]).
#[derive(Debug)]
struct InFlight {
    body: usize,
    tool: usize,
    incision: u64,
    /// The incision's mark of the strips it cuts with.
    mark: u64,
    /// The step it is due in: it lands then, or with
    /// [`crate::mesh::cut::CutOptions::land_when_ready`] at the first step after that in which
    /// its preparation is done.
    due: u64,
    job: super::CutJob,
    /// Balls of vaporized tissue it carves out (none: a blade's cut).
    vaporized: Vec<crate::mesh::cut::Ball>,
}

impl SoftTissueWorld {
    /// An empty world.
    pub fn new(config: WorldConfig) -> Result<Self, WorldError> {
        if !(config.dt.is_finite() && config.dt > 0.0) {
            return Err(WorldError::TimeStep(format!(
                "world step {} must be finite and > 0",
                config.dt
            )));
        }
        config
            .contact
            .validate()
            .map_err(|source| WorldError::Contact {
                name: "world".into(),
                source,
            })?;
        Ok(SoftTissueWorld {
            config,
            bodies: Vec::new(),
            cut_loads: Vec::new(),
            tools: Vec::new(),
            obstacles: Vec::new(),
            contacts: ContactState::default(),
            steps: 0,
            accumulator: 0.0,
            times: StageTimes::default(),
            threads: crate::parallel::Threads::new(crate::parallel::default_threads())?,
            halted: None,
            cut_options: Default::default(),
            uncut: Vec::new(),
            incisions: Vec::new(),
            in_flight: Vec::new(),
        })
    }

    /// How blades cut (default [`crate::mesh::cut::CutOptions::default`]).
    pub fn set_cut_options(
        &mut self,
        options: crate::mesh::cut::CutOptions,
    ) -> Result<(), WorldError> {
        if !(crate::mesh::cut::MIN_SNAP..0.5).contains(&options.snap) {
            return Err(WorldError::Cut {
                body: "world".into(),
                reason: crate::mesh::cut::CutError::BadSnap(options.snap).to_string(),
            });
        }
        self.cut_options = options;
        Ok(())
    }

    /// Cuts body `index` along `blade` now (see [`WorldBody::cut`]): pieces that came loose
    /// are added as bodies, grips on the body follow its nodes. Returns the indices of the
    /// new bodies (empty when nothing was separated).
    pub fn cut_body(
        &mut self,
        index: usize,
        blade: &[crate::mesh::cut::CutTriangle],
    ) -> Result<Vec<usize>, WorldError> {
        self.cut_body_within(index, blade, &[], 0)
    }

    /// [`SoftTissueWorld::cut_body`] by incision `incision`'s newest strip `blade`, its
    /// stroke so far `region` (see [`WorldBody::cut_within`]).
    pub fn cut_body_within(
        &mut self,
        index: usize,
        blade: &[crate::mesh::cut::CutTriangle],
        region: &[crate::mesh::cut::CutTriangle],
        incision: u64,
    ) -> Result<Vec<usize>, WorldError> {
        if index >= self.bodies.len() {
            return Err(WorldError::Unknown {
                kind: "body",
                name: index.to_string(),
            });
        }
        let cut = match self.bodies[index].cut_within(blade, region, incision, &self.cut_options)? {
            super::cut::BladeOutcome::Cut(c) => *c,
            _ => return Ok(Vec::new()),
        };
        self.add_cut(index, cut)
    }

    /// Adds the pieces of body `index`'s cut as bodies (names made unique), keeps the body
    /// as it was before its first cut for `reset`, moves grips; returns the new indices. The
    /// kept body and the pieces take the frame of a body that was moved
    /// ([`WorldBody::carry_frame`]).
    fn add_cut(
        &mut self,
        index: usize,
        mut cut: super::cut::BladeCut,
    ) -> Result<Vec<usize>, WorldError> {
        self.bodies[index].carry_frame(&mut cut)?;
        let first = self.bodies.len();
        let super::cut::BladeCut {
            pieces,
            previous,
            node_map,
            ..
        } = cut;
        if !previous.loose && !self.uncut.iter().any(|(k, _)| *k == index) {
            self.uncut.push((index, *previous));
        }
        let mut made = Vec::with_capacity(pieces.len());
        for mut p in pieces {
            // A name no other body has (a user's body may already be called `NAME.k`).
            let base = p.name.clone();
            let mut k = 1;
            while self.bodies.iter().any(|b| b.name == p.name) {
                p.name = format!("{base}.{k}");
                k += 1;
            }
            made.push(self.bodies.len());
            self.bodies.push(p);
        }
        // Every blade's strips pending for the body are pending for its pieces too.
        for inc in self.incisions.iter_mut().flatten() {
            for &p in &made {
                inc.inherit(index as u64, p as u64);
            }
        }
        super::cut::remap_grips(&mut self.tools, &self.bodies, index, &node_map, first);
        Ok(made)
    }

    /// The cut stage: every blade with cutting on cuts the bodies its edge crossed since the
    /// last step. With [`crate::mesh::cut::CutOptions::background_steps`] above 0, a cut is
    /// prepared on a thread of its own and lands that many steps later (in the order the
    /// cuts began; with `land_when_ready`, once due and done); a body being cut is not cut
    /// again before its cut lands.
    fn cut_stage(&mut self) -> Result<(), WorldError> {
        self.incisions.resize(self.tools.len(), None);
        let cutting = |t: &Tool| t.cutting() && t.blade_sweep().is_some();
        // Tissue an electrode vaporized and not yet carved (or refused until it grows) is
        // checked without allocating.
        let craters = self.bodies.iter().any(WorldBody::has_vaporized);
        if self.in_flight.is_empty() && !self.tools.iter().any(cutting) && !craters {
            // Nothing to cut (and nothing allocated for it).
            self.incisions.iter_mut().for_each(|i| *i = None);
            return Ok(());
        }
        // Bodies made by this stage are not cut again in it.
        let count = self.bodies.len();
        let mut strokes: Vec<Option<Vec<crate::mesh::cut::CutTriangle>>> =
            Vec::with_capacity(self.tools.len());
        for t in 0..self.tools.len() {
            let tool = &self.tools[t];
            let sweep = tool.blade_sweep().filter(|_| tool.cutting());
            let Some([from, to]) = sweep else {
                self.incisions[t] = None;
                strokes.push(None);
                continue;
            };
            let incision = self.incisions[t].get_or_insert_with(|| super::cut::Incision::new(from));
            strokes.push(Some(incision.advance(to)));
        }
        // Cuts due land first (those not ready yet wait for a later step where the options
        // say so).
        let mut k = 0;
        while k < self.in_flight.len() {
            let f = &self.in_flight[k];
            if f.due > self.steps || (self.cut_options.land_when_ready && !f.job.is_ready()) {
                k += 1;
                continue;
            }
            let f = self.in_flight.remove(k);
            let outcome = self.bodies[f.body].finish_cut(f.job);
            self.times.cut_wait_us += self.bodies[f.body].landing_wait_us;
            let outcome = outcome?;
            if !f.vaporized.is_empty() {
                self.vaporize_landed(f.body, &f.vaporized, outcome)?;
            } else {
                self.cut_landed(f.tool, f.incision, f.body, f.mark, outcome)?;
            }
        }
        let background = self.cut_options.background_steps;
        for (t, stroke) in strokes.iter().enumerate() {
            let Some(stroke) = stroke else { continue };
            for i in 0..count {
                if self.in_flight.iter().any(|f| f.body == i) {
                    continue;
                }
                let Some(inc) = self.incisions[t].as_ref() else {
                    break;
                };
                let id = inc.id();
                let (strips, mark) = inc.pending(i as u64);
                if strips.is_empty() {
                    continue;
                }
                let place = if background > 0 {
                    super::CutPlace::Pool(&self.threads)
                } else {
                    super::CutPlace::Here
                };
                let job =
                    self.bodies[i].begin_cut_at(&strips, stroke, id, &self.cut_options, place)?;
                match job {
                    None => self.cut_landed(t, id, i, mark, super::BladeOutcome::Missed)?,
                    Some(job) if background == 0 => {
                        let outcome = self.bodies[i].finish_cut(job)?;
                        self.cut_landed(t, id, i, mark, outcome)?;
                    }
                    Some(job) => self.in_flight.push(InFlight {
                        body: i,
                        tool: t,
                        incision: id,
                        mark,
                        due: self.steps + background as u64,
                        job,
                        vaporized: Vec::new(),
                    }),
                }
            }
        }
        if craters {
            self.vaporize_stage(count)?;
        }
        Ok(())
    }

    /// Tissue electrodes vaporized leaves the bodies (see [`WorldBody::vaporized`]), as a
    /// cut changes them: in the step or in the background like a blade's cuts.
    fn vaporize_stage(&mut self, count: usize) -> Result<(), WorldError> {
        let background = self.cut_options.carve_steps();
        for i in 0..count {
            if self.in_flight.iter().any(|f| f.body == i) {
                continue;
            }
            let balls = self.bodies[i].vaporized();
            let place = if background > 0 {
                super::CutPlace::Pool(&self.threads)
            } else {
                super::CutPlace::Here
            };
            let Some(job) =
                self.bodies[i].begin_vaporize(balls.clone(), &self.cut_options, place)?
            else {
                continue;
            };
            if background == 0 {
                let outcome = self.bodies[i].finish_cut(job)?;
                self.vaporize_landed(i, &balls, outcome)?;
            } else {
                self.in_flight.push(InFlight {
                    body: i,
                    tool: usize::MAX,
                    incision: 0,
                    mark: 0,
                    due: self.steps + background as u64,
                    job,
                    vaporized: balls,
                });
            }
        }
        Ok(())
    }

    /// The carving of `balls` of vaporized tissue out of body `body` came to `outcome`.
    fn vaporize_landed(
        &mut self,
        body: usize,
        balls: &[crate::mesh::cut::Ball],
        outcome: super::BladeOutcome,
    ) -> Result<(), WorldError> {
        match outcome {
            super::BladeOutcome::Cut(c) => {
                self.add_cut(body, *c)?;
            }
            // Refused by the mesh (a warning said why, or nothing was inside): tried again once
            // its balls have grown by `CARVE_GROWTH`.
            super::BladeOutcome::Missed => self.bodies[body].vaporize_refused(balls),
            // Dropped for now (the body was built again, or moved so an element would
            // invert): tried again next step.
            super::BladeOutcome::Crossed => {}
        }
        Ok(())
    }

    /// A cut of body `body` by tool `tool`'s incision `incision` with its strips up to
    /// `mark` came to `outcome`: the pieces are added, and the strips are no longer pending
    /// for the body and its pieces unless they crossed it without separating anything.
    fn cut_landed(
        &mut self,
        tool: usize,
        incision: u64,
        body: usize,
        mark: u64,
        outcome: super::BladeOutcome,
    ) -> Result<(), WorldError> {
        let made = match outcome {
            super::BladeOutcome::Crossed => return Ok(()),
            super::BladeOutcome::Missed => Vec::new(),
            super::BladeOutcome::Cut(c) => self.add_cut(body, *c)?,
        };
        if let Some(Some(inc)) = self.incisions.get_mut(tool)
            && inc.id() == incision
        {
            inc.consumed(body as u64, mark);
            for p in made {
                inc.consumed(p as u64, mark);
            }
        }
        Ok(())
    }

    /// Cuts (and removals of vaporized tissue) being prepared beside the steps (see
    /// [`crate::mesh::cut::CutOptions::background_steps`]).
    pub fn cuts_in_flight(&self) -> usize {
        self.in_flight.len()
    }

    /// Settings.
    pub fn config(&self) -> &WorldConfig {
        &self.config
    }

    /// Adds a body; its solver step must be the world's.
    pub fn add_body(&mut self, body: WorldBody) -> Result<usize, WorldError> {
        let dt = body.model.settings().dt;
        if (dt - self.config.dt).abs() > 1e-12 * self.config.dt {
            return Err(WorldError::TimeStep(format!(
                "body `{}` steps {dt} s but the world steps {} s",
                body.name, self.config.dt
            )));
        }
        if self.bodies.iter().any(|b| b.name == body.name) {
            return Err(WorldError::DuplicateName(body.name));
        }
        self.bodies.push(body);
        Ok(self.bodies.len() - 1)
    }

    /// Adds a tool.
    pub fn add_tool(&mut self, tool: Tool) -> usize {
        self.tools.push(tool);
        self.tools.len() - 1
    }

    /// Adds a static obstacle; its name must be new among the obstacles.
    pub fn add_obstacle(&mut self, obstacle: Obstacle) -> Result<usize, WorldError> {
        if self.obstacles.iter().any(|o| o.name() == obstacle.name()) {
            return Err(WorldError::DuplicateName(obstacle.name().to_string()));
        }
        self.obstacles.push(obstacle);
        Ok(self.obstacles.len() - 1)
    }

    /// Static obstacles.
    pub fn obstacles(&self) -> &[Obstacle] {
        &self.obstacles
    }

    /// Static obstacles, to move or change between steps.
    pub fn obstacles_mut(&mut self) -> &mut [Obstacle] {
        &mut self.obstacles
    }

    /// Bodies.
    pub fn bodies(&self) -> &[WorldBody] {
        &self.bodies
    }

    /// A 64-bit hash (FNV-1a) of the bits of every node position of every body, in body and
    /// node order: equal states give equal hashes, so replays (and runs with other settings
    /// that must not change the result) can be compared by one number.
    pub fn state_hash(&self) -> u64 {
        let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
        for b in &self.bodies {
            for p in b.model().node_positions() {
                for c in p.iter() {
                    for byte in c.to_bits().to_le_bytes() {
                        hash ^= u64::from(byte);
                        hash = hash.wrapping_mul(0x0100_0000_01b3);
                    }
                }
            }
        }
        hash
    }

    /// Bodies, to change.
    pub fn bodies_mut(&mut self) -> &mut [WorldBody] {
        &mut self.bodies
    }

    /// Index of the body named `name`.
    pub fn body_index(&self, name: &str) -> Result<usize, WorldError> {
        self.bodies
            .iter()
            .position(|b| b.name == name)
            .ok_or_else(|| WorldError::Unknown {
                kind: "body",
                name: name.into(),
            })
    }

    /// Tools.
    pub fn tools(&self) -> &[Tool] {
        &self.tools
    }

    /// Tools, to move and operate.
    pub fn tools_mut(&mut self) -> &mut [Tool] {
        &mut self.tools
    }

    /// Contacts of the last step: the start-of-step detection, and the rows of the contact
    /// solve with their forces.
    pub fn contacts(&self) -> &ContactState {
        &self.contacts
    }

    /// Fixed steps run so far.
    pub fn step_count(&self) -> u64 {
        self.steps
    }

    /// Simulated time, s.
    pub fn time(&self) -> f64 {
        self.steps as f64 * self.config.dt
    }

    /// Stage times of the last step.
    pub fn stage_times(&self) -> StageTimes {
        self.times
    }

    /// Advances by `dt` seconds of frame time: runs as many fixed steps as the accumulated
    /// time holds (the remainder carries over). Returns the number of steps run.
    pub fn step(&mut self, dt: f64) -> Result<u32, WorldError> {
        if !(dt.is_finite() && dt >= 0.0) {
            return Err(WorldError::TimeStep(format!(
                "frame time {dt} must be finite and >= 0"
            )));
        }
        self.accumulator += dt;
        let mut n = 0;
        // A tolerance so 0.02 + 0.02 + ... does not drop a step to round-off.
        while self.accumulator >= self.config.dt * (1.0 - 1e-9) {
            self.accumulator -= self.config.dt;
            self.step_fixed()?;
            n += 1;
        }
        Ok(n)
    }

    /// The threads steps run on.
    pub fn threads(&self) -> &crate::parallel::Threads {
        &self.threads
    }

    /// Sets the number of threads steps run on (0: every available core, the default; 1:
    /// the caller's thread only). The results do not depend on it: the same inputs give
    /// bit-identical states for every count.
    pub fn set_threads(&mut self, count: usize) -> Result<(), WorldError> {
        self.threads = crate::parallel::Threads::new(count)?;
        Ok(())
    }

    /// Runs exactly one fixed step through every stage (in the world's thread pool).
    ///
    /// A stage that fails stops the step there (the later stages do not run) and leaves the
    /// bodies as it found them: a solver step that fails leaves its body unchanged (bodies
    /// that finished their step before it keep it), the contact response is undone as a
    /// whole, and no non-finite surface is written. The world then refuses to step
    /// ([`WorldError::Halted`]) until [`SoftTissueWorld::resume`] (carry on from that state,
    /// for instance after removing the cause) or [`SoftTissueWorld::reset`].
    pub fn step_fixed(&mut self) -> Result<(), WorldError> {
        if let Some(cause) = &self.halted {
            return Err(WorldError::Halted(cause.clone()));
        }
        let threads = self.threads.clone();
        let result = threads.run(|| self.step_stages());
        if let Err(e) = &result {
            self.halted = Some(e.to_string());
        }
        result
    }

    /// The error of the failed step that stopped the world, if it is stopped.
    pub fn halted(&self) -> Option<&str> {
        self.halted.as_deref()
    }

    /// Lets a stopped world step again from the state its failed step left (see
    /// [`SoftTissueWorld::step_fixed`]).
    pub fn resume(&mut self) {
        self.halted = None;
    }

    fn step_stages(&mut self) -> Result<(), WorldError> {
        let dt = self.config.dt;
        let c = self.config.contact;
        let mut t = Instant::now();
        let lap = |t: &mut Instant| {
            let e = t.elapsed().as_secs_f64() * 1e6;
            *t = Instant::now();
            e
        };
        // A blade's resistance on the bodies as the step began; its pull on them after the
        // cut stage (a cut landing now replaced the body).
        self.times.cut_wait_us = 0.0;
        let mut loads = std::mem::take(&mut self.cut_loads);
        super::cut_force::cutting_resistance(&mut self.tools, &self.bodies, &mut loads);
        self.cut_stage()?;
        let loaded = super::cut_force::load_cutting(&mut self.bodies, &loads);
        self.cut_loads = loads;
        loaded?;
        self.times.cut_us = lap(&mut t);
        prepare(&mut self.bodies, &mut self.tools, dt);
        self.times.prepare_us = lap(&mut t);
        detect_contacts(&mut self.bodies, &mut self.tools, &c, &mut self.contacts);
        self.times.detect_us = lap(&mut t);
        switch_precision(&mut self.bodies)?;
        self.times.switch_us = lap(&mut t);
        step_solvers(&mut self.bodies, &self.tools, &self.contacts)?;
        self.times.solve_us = lap(&mut t);
        let solved = solve_contacts(
            &mut self.bodies,
            &mut self.tools,
            &self.obstacles,
            &c,
            &mut self.contacts,
        );
        let whole = lap(&mut t);
        let s = self.contacts.stats();
        self.times.correct_us = s.correct_us.min(whole);
        self.times.contact_us = whole - self.times.correct_us;
        solved?;
        writeback(&mut self.bodies)?;
        self.times.writeback_us = lap(&mut t);
        self.steps += 1;
        Ok(())
    }

    /// Back to the initial state: every body at rest at the cage level in its rest shape,
    /// tools idle at the origin, counters cleared. A run after `reset` repeats the first run
    /// bit for bit given the same inputs.
    pub fn reset(&mut self) -> Result<(), WorldError> {
        // Cut bodies come back whole; pieces that came loose go.
        for (k, b) in self.uncut.drain(..) {
            self.bodies[k] = b;
        }
        self.bodies.retain(|b| !b.loose);
        self.incisions.clear();
        // Cuts being prepared are dropped (their threads end on their own).
        self.in_flight.clear();
        for b in &mut self.bodies {
            b.reset()?;
        }
        for t in &mut self.tools {
            t.reset();
        }
        // Cleared, not replaced: the workspaces keep their room, so a run after a reset does
        // not allocate either.
        self.contacts.clear();
        self.steps = 0;
        self.accumulator = 0.0;
        self.times = StageTimes::default();
        self.halted = None;
        Ok(())
    }
}
