//! A heat field's electrodes and sample points: the sub-grid spots (see `spot.rs`) as the
//! field keeps them, and the points where temperature and damage are followed finer than
//! the mesh.

use super::spot::{ELECTRODE_RADIUS_RANGE, RETIRE_KELVIN, arrhenius};
use super::*;

impl HeatField {
    /// Heats through an electrode for the next step: `source.watts` into the tissue at
    /// `source.center` (rest, scene units), where the coarse field is interpolated by
    /// `nodes` (node, weight; weights summing to 1). The power goes into the spot already at
    /// that place (within half an electrode radius; it keeps its own tissue fraction) or a
    /// new one; see the module `spot` for the model.
    pub fn add_electrode(
        &mut self,
        source: &ElectrodeSource,
        nodes: &[(usize, f64)],
    ) -> Result<(), HeatError> {
        self.heat_at_electrode(source, nodes, 0)
    }

    /// [`HeatField::add_electrode`] by electrode `electrode` (a world's tool index): the
    /// spot it heats remembers it, so [`HeatField::powered_spot`] finds each electrode's own
    /// spot (two electrodes of one radius on a body each theirs).
    pub fn add_electrode_of(
        &mut self,
        electrode: u32,
        source: &ElectrodeSource,
        nodes: &[(usize, f64)],
    ) -> Result<(), HeatError> {
        self.heat_at_electrode(source, nodes, super::spot::electrode_bit(electrode))
    }

    /// [`HeatField::add_electrode`], the spot marked with `electrodes` (bits of
    /// [`super::spot::electrode_bit`]; 0 for an electrode without a number).
    fn heat_at_electrode(
        &mut self,
        source: &ElectrodeSource,
        nodes: &[(usize, f64)],
        electrodes: u64,
    ) -> Result<(), HeatError> {
        let n = self.temperature.len();
        let first = nodes.first().map_or(0, |x| x.0);
        let bad = |what: &'static str, value: f64| HeatError::NonFinite {
            what,
            node: first,
            value,
        };
        if !(source.watts.is_finite() && source.watts >= 0.0) {
            return Err(bad("electrode power", source.watts));
        }
        if !(source.radius.is_finite() && source.radius > 0.0) {
            return Err(HeatError::BadParameter {
                field: "electrode radius",
                value: source.radius,
                expected: "finite and > 0",
            });
        }
        if !(source.tissue_fraction > 0.0 && source.tissue_fraction <= 1.0) {
            return Err(HeatError::BadParameter {
                field: "electrode tissue_fraction",
                value: source.tissue_fraction,
                expected: "in (0, 1]",
            });
        }
        if !source.center.iter().all(|c| c.is_finite()) {
            return Err(bad("electrode centre", source.center.norm()));
        }
        if nodes.is_empty() {
            return Err(HeatError::BadParameter {
                field: "electrode nodes",
                value: 0.0,
                expected: "at least one node",
            });
        }
        for &(node, _) in nodes {
            if node >= n {
                return Err(HeatError::BadNode { node, nodes: n });
            }
        }
        check_weights(
            nodes.iter().map(|&(i, w)| (i, w)),
            "electrode weights",
            true,
        )?;
        if !ELECTRODE_RADIUS_RANGE.contains(&source.radius) {
            return Err(HeatError::BadParameter {
                field: "electrode radius",
                value: source.radius,
                expected: "from 1e-5 to 0.05 m",
            });
        }
        if source.watts == 0.0 {
            return Ok(());
        }
        let k = match self.spot_index(&source.center, source.radius) {
            Some(k) => k,
            None => {
                if self.spots.len() >= MAX_SPOTS
                    && let Some(old) = self.spots.iter().position(|p| p.power == 0.0)
                {
                    self.retire(old);
                    self.changed = true;
                    self.version += 1;
                }
                let grid = match self.grids.iter().find(|g| g.radius == source.radius) {
                    Some(g) => g.clone(),
                    None => {
                        let g = Arc::new(RadialGrid::new(source.radius, &self.params, self.dt));
                        self.grids.push(g.clone());
                        g
                    }
                };
                let nodes: Vec<(u32, f64)> = nodes.iter().map(|&(i, w)| (i as u32, w)).collect();
                let centre = interpolate(&self.temperature, &nodes);
                let near = self.near_nodes(&source.center, grid.outer);
                self.spots.push(Spot::new(
                    source.center,
                    nodes,
                    source.tissue_fraction,
                    grid,
                    &near,
                    centre,
                ));
                let k = self.spots.len() - 1;
                let mut base = vec![0.0; SPOT_SHELLS];
                self.shell_bases(k, &mut base);
                self.spots[k].start_bases(base);
                k
            }
        };
        self.spots[k].power += source.watts;
        self.spots[k].electrodes |= electrodes;
        Ok(())
    }

    /// The spot an electrode of `radius` (m) at `center` (rest, scene units) heats: one of
    /// that radius within half of it. Its tissue fraction stays the one it was made with.
    fn spot_index(&self, center: &Vec3, radius: f64) -> Option<usize> {
        let s = self.params.meters_per_unit;
        self.spots
            .iter()
            .position(|p| p.grid.radius == radius && (p.center - center).norm() * s < 0.5 * radius)
    }

    /// The tissue fraction of the spot an electrode of `radius` (m) at `center` (rest, scene
    /// units) would heat, if there is one ([`HeatField::add_electrode`] adds to it; its
    /// fraction was set when it was made, so a caller need not measure one again).
    pub fn spot_fraction_at(&self, center: &Vec3, radius: f64) -> Option<f64> {
        self.spot_index(center, radius)
            .map(|k| self.spots[k].fraction)
    }

    /// The newest spot of `radius` (m) that electrode `electrode` (a world's tool index, as
    /// given to [`HeatField::add_electrode_of`]) powered in the last step: its centre, coarse
    /// nodes and tissue fraction (where the electrode goes on heating in a step whose
    /// contact rows no longer fit the mesh: a carve just landed). Electrodes 64 apart in
    /// number are not told apart.
    pub fn powered_spot(&self, electrode: u32, radius: f64) -> Option<SpotPlace> {
        let bit = super::spot::electrode_bit(electrode);
        self.spots
            .iter()
            .rev()
            .find(|p| p.powered && p.powered_by & bit != 0 && p.grid.radius == radius)
            .map(|p| SpotPlace {
                center: p.center,
                nodes: p.nodes.iter().map(|&(i, w)| (i as usize, w)).collect(),
                tissue_fraction: p.fraction,
            })
    }

    /// Each spot's centre (rest, scene units), electrode radius (m) and tissue fraction,
    /// oldest first.
    pub fn spot_places(&self) -> impl Iterator<Item = (Vec3, f64, f64)> + '_ {
        self.spots
            .iter()
            .map(|p| (p.center, p.grid.radius, p.fraction))
    }

    /// Power queued at electrodes for the next step, W.
    pub fn queued_electrode_power(&self) -> f64 {
        self.spots.iter().map(|p| p.power).sum()
    }

    /// Spots (places an electrode heated whose heat is still above the coarse field).
    pub fn spot_count(&self) -> usize {
        self.spots.len()
    }

    /// Temperature at `position` (rest, scene units) where the coarse field is interpolated
    /// by `nodes`: the coarse value plus the excess of every spot, C. A node out of range
    /// is refused by name.
    pub fn temperature_at(&self, position: &Vec3, nodes: &[(u32, f64)]) -> Result<f64, HeatError> {
        let n = self.temperature.len();
        if let Some(&(node, _)) = nodes.iter().find(|x| x.0 as usize >= n) {
            return Err(HeatError::BadNode {
                node: node as usize,
                nodes: n,
            });
        }
        Ok(self.temperature_at_unchecked(position, nodes))
    }

    /// The base temperature of each shell of spot `k` into `out`, C: the coarse field around
    /// it at that radius and the other spots' excess averaged over the shell's sphere (see
    /// [`Spot::coarse_bases`], [`Spot::add_sphere_means`]).
    pub(super) fn shell_bases(&self, k: usize, out: &mut [f64]) {
        let s = self.params.meters_per_unit;
        let spot = &self.spots[k];
        let centre = interpolate(&self.temperature, &spot.nodes);
        let rho_c = self.params.density * self.params.specific_heat;
        spot.coarse_bases(&self.temperature, &self.capacity, rho_c, centre, out);
        let r = spot.grid.shell_radii();
        for (j, other) in self.spots.iter().enumerate() {
            if j != k {
                other.add_sphere_means(&spot.center, s, r, out);
            }
        }
    }

    /// The nodes whose lumped volume (taken as a ball about the node) reaches within
    /// `outer` (m) of `centre` (scene units): node, distance and that ball's radius, m.
    fn near_nodes(&self, centre: &Vec3, outer: f64) -> Vec<(u32, f64, f64)> {
        let s = self.params.meters_per_unit;
        let rho_c = self.params.density * self.params.specific_heat;
        let ball = 3.0 / (4.0 * std::f64::consts::PI * rho_c);
        (0..self.positions.len())
            .filter_map(|i| {
                let d = (self.positions[i] - centre).norm() * s;
                let a = (ball * self.capacity[i]).cbrt();
                (d - a < outer && a > 0.0).then_some((i as u32, d, a))
            })
            .collect()
    }

    fn temperature_at_unchecked(&self, position: &Vec3, nodes: &[(u32, f64)]) -> f64 {
        let s = self.params.meters_per_unit;
        interpolate(&self.temperature, nodes)
            + self
                .spots
                .iter()
                .map(|p| p.excess_at(position, s))
                .sum::<f64>()
    }

    /// The largest temperature, at a node or an electrode, C (NaN if any is).
    pub fn max_temperature(&self) -> f64 {
        let coarse = self
            .temperature
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, crate::state::nan_max);
        self.spots
            .iter()
            .map(Spot::max_temperature)
            .fold(coarse, crate::state::nan_max)
    }

    /// Burnt volumes at the sub-grid scale, of the spots now and of those that ended, m^3.
    /// Places where spots overlap count once for each.
    pub fn burn_volumes(&self) -> BurnVolumes {
        let mut v = self.retired;
        for p in &self.spots {
            v += p.volumes(&self.params);
        }
        v
    }

    /// Radius of the coagulated zone (damage at least 1) around each live spot, m.
    pub fn coagulated_radii(&self) -> Vec<f64> {
        self.spots.iter().map(|p| p.coagulated_radius()).collect()
    }

    /// Radius of the crater around each live spot (the electrode's radius where nothing
    /// vaporized), m: how far the electrode has burnt its way in.
    pub fn crater_radii(&self) -> Vec<f64> {
        self.spots.iter().map(|p| p.crater_radius()).collect()
    }

    /// Per spot with a crater: its centre (rest, scene units), the radius of the ball whose
    /// volume is the tissue it vaporized, `cbrt(crater^3 - electrode^3)` (the electrode's own
    /// place, where the rest shape still has tissue, is tissue it pushed aside, not burnt),
    /// and the electrode's radius, m.
    pub fn vaporized_balls(&self) -> Vec<(Vec3, f64, f64)> {
        self.vaporized_balls_iter().collect()
    }

    /// [`HeatField::vaporized_balls`] without allocating.
    pub fn vaporized_balls_iter(&self) -> impl Iterator<Item = (Vec3, f64, f64)> + '_ {
        self.spots.iter().filter(|p| p.has_crater()).map(|p| {
            let (rc, re) = (p.crater_radius(), p.grid.radius);
            (p.center, (rc.powi(3) - re.powi(3)).max(0.0).cbrt(), re)
        })
    }

    /// The nodes' temperatures with every spot's heat given to the free nodes within its
    /// reach (see `HeatField::spread`: each takes at most the spot's excess at it, the rest
    /// evenly; the spot's own nodes where none is within reach): what a cut or a carve hands
    /// to the pieces, C.
    pub fn temperatures_with_spots(&self) -> Vec<f64> {
        let mut t = self.temperature.clone();
        for spot in &self.spots {
            self.spread(spot, &mut t);
        }
        t
    }

    /// Adds `spot`'s excess heat to the node temperatures `t` where it lies: each free node
    /// within its reach takes the spot's excess at it, scaled down where those excesses hold
    /// more heat than the spot (by the ratio), and where they hold less the rest goes evenly
    /// (the same rise) to all of them. No node rises by more than the excess at it plus that
    /// even share. Scaled up instead (as before), a spot whose hot core the mesh does not
    /// sample (a crater's few fine nodes at its wall) put its heat into them by hundreds of
    /// times their excess: thousands of kelvin. At the spot's own nodes where no node is
    /// within reach.
    fn spread(&self, spot: &Spot, t: &mut [f64]) {
        let energy = spot.sensible_energy();
        let s = self.params.meters_per_unit;
        let reach = spot.grid.outer / s;
        let within =
            |i: usize| self.fixed[i].is_none() && (self.positions[i] - spot.center).norm() < reach;
        let (mut held, mut capacity) = (0.0, 0.0);
        for i in (0..t.len()).filter(|&i| within(i)) {
            held += spot.excess_at(&self.positions[i], s).max(0.0) * self.capacity[i];
            capacity += self.capacity[i];
        }
        if capacity > 0.0 && held.is_finite() {
            let scale = if held > 0.0 {
                (energy / held).clamp(-1.0, 1.0)
            } else {
                0.0
            };
            let even = (energy - scale * held) / capacity;
            for (i, ti) in t.iter_mut().enumerate() {
                if within(i) {
                    *ti += scale * spot.excess_at(&self.positions[i], s).max(0.0) + even;
                }
            }
        } else {
            for &(node, w) in &spot.nodes {
                let i = node as usize;
                if self.fixed[i].is_none() {
                    t[i] += w * energy / self.capacity[i];
                }
            }
        }
    }

    /// The craters the electrodes vaporized: each spot's centre (rest, scene units) and
    /// crater radius (m), where it is larger than the electrode.
    pub fn craters(&self) -> Vec<(Vec3, f64)> {
        self.spots
            .iter()
            .filter(|p| p.has_crater())
            .map(|p| (p.center, p.crater_radius()))
            .collect()
    }

    /// Whether an electrode has vaporized a crater (cheap: no allocation).
    pub fn has_craters(&self) -> bool {
        self.spots.iter().any(Spot::has_crater)
    }

    /// Takes `other`'s burns as its own history (a body's field after a cut or a carve of
    /// vaporized tissue): its burnt volumes and the heat its water took, of its spots and of
    /// those that ended, so the totals go on, and what they burnt where (samples set later
    /// start from it).
    pub fn carry_burns_from(&mut self, other: &HeatField) {
        self.retired = other.burn_volumes();
        // The heat the spots' water took and their vaporized tissue's (both left as steam),
        // as when a spot ends.
        self.retired_boiled = other.retired_boiled
            + other
                .spots
                .iter()
                .map(|p| p.boiled_energy() + p.vaporized_sensible_energy())
                .sum::<f64>();
        self.marks = other.marks.clone();
        self.departed = other.departed;
        for spot in &other.spots {
            self.keep_mark(spot.mark());
        }
        self.changed = true;
        self.version += 1;
    }

    /// Takes `other`'s burn history and its spots, which go on in this field: a body's field
    /// after a carve that left it one piece (the rest shape about the spots is the one they
    /// burnt, less the carved balls they vaporized). A spot stands at this field's node
    /// nearest its centre (its own nodes were carved away): the nearest of the nodes within
    /// its reach, found for its shells' bases anyway (a node without tissue about it is
    /// none), else `nearest(centre)`'s nodes and weights. This field's temperatures must be
    /// `other`'s coarse field without the spots ([`HeatField::temperatures`]), so the
    /// spots' heat is neither lost nor counted twice.
    pub fn carry_spots_from(
        &mut self,
        other: &HeatField,
        nearest: impl Fn(&Vec3) -> Vec<(u32, f64)>,
    ) {
        self.retired = other.retired;
        self.retired_boiled = other.retired_boiled;
        self.marks = other.marks.clone();
        self.departed = other.departed;
        for spot in &other.spots {
            let mut p = spot.clone();
            let near = self.near_nodes(&p.center, p.grid.outer);
            // Every node with tissue closer than the reach is in `near`, in node order (the
            // first of equally near ones wins, as in a scan of all nodes).
            let distance = |i: u32| (self.positions[i as usize] - p.center).norm();
            let closest = near
                .iter()
                .filter(|n| n.1 < p.grid.outer)
                .map(|n| n.0)
                .min_by(|&a, &b| distance(a).total_cmp(&distance(b)));
            let nodes = match closest {
                Some(i) => vec![(i, 1.0)],
                None => nearest(&p.center),
            };
            p.rebind(nodes, &near);
            if !self.grids.iter().any(|g| Arc::ptr_eq(g, &p.grid)) {
                self.grids.push(p.grid.clone());
            }
            self.spots.push(p);
        }
        self.changed = true;
        self.version += 1;
    }

    /// Takes `other`'s burn marks (what its spots burnt where), without its burnt volumes or
    /// the heat its water took: a piece a cut took off a body, which keeps those (counted
    /// once), draws the burn on its part all the same.
    pub fn carry_marks_from(&mut self, other: &HeatField) {
        self.marks = other.marks.clone();
        for spot in &other.spots {
            self.keep_mark(spot.mark());
        }
        self.changed = true;
        self.version += 1;
    }

    /// Follows temperature, damage and peak temperature at `samples` (see [`HeatSample`]);
    /// replaces the points followed before. Their damage and peak start from what spots
    /// that ended burnt there, what the body's spots had burnt before its mesh changed
    /// (a cut, a carve; [`HeatField::carry_burns_from`]) and what its spots burnt (spots
    /// carried over a carve, [`HeatField::carry_spots_from`]), else at zero and the
    /// temperature now.
    pub fn set_samples(&mut self, samples: Vec<HeatSample>) -> Result<(), HeatError> {
        let n = self.temperature.len();
        for p in &samples {
            for &(node, _) in &p.nodes {
                if node as usize >= n {
                    return Err(HeatError::BadNode {
                        node: node as usize,
                        nodes: n,
                    });
                }
            }
            // A point slightly outside its tetrahedron has a negative weight (an embedded
            // surface's vertex): allowed here.
            check_weights(
                p.nodes.iter().map(|&(i, w)| (i as usize, w)),
                "sample weights",
                false,
            )?;
            if !p.position.iter().all(|c| c.is_finite()) {
                return Err(HeatError::NonFinite {
                    what: "sample position",
                    node: p.nodes[0].0 as usize,
                    value: p.position.norm(),
                });
            }
        }
        self.sample_temperature = samples
            .iter()
            .map(|p| self.temperature_at_unchecked(&p.position, &p.nodes))
            .collect();
        self.sample_peak = self.sample_temperature.clone();
        self.sample_damage = vec![0.0; samples.len()];
        // Burns of spots that ended, or of the body before its mesh changed, show at the new
        // samples: each starts with the most damage and highest peak a mark has there (and
        // at least the nodes' damage there).
        let s = self.params.meters_per_unit;
        let live: Vec<super::spot::BurnMark> = self.spots.iter().map(Spot::mark).collect();
        for (k, p) in samples.iter().enumerate() {
            self.sample_damage[k] = interpolate(&self.damage, &p.nodes).max(0.0);
            for m in self.marks.iter().chain(&live) {
                if let Some((damage, peak)) = m.at((p.position - m.center).norm() * s) {
                    self.sample_damage[k] = self.sample_damage[k].max(damage);
                    self.sample_peak[k] = self.sample_peak[k].max(peak);
                }
            }
        }
        self.samples = samples;
        Ok(())
    }

    /// Temperature at each sample, C.
    pub fn sample_temperatures(&self) -> &[f64] {
        &self.sample_temperature
    }

    /// Arrhenius damage integral at each sample.
    pub fn sample_damage(&self) -> &[f64] {
        &self.sample_damage
    }

    /// The largest temperature each sample reached, C.
    pub fn sample_peaks(&self) -> &[f64] {
        &self.sample_peak
    }

    /// Takes the spots' solved steps; spots with no power whose excess has faded end.
    pub(super) fn commit_spots(&mut self) {
        if self.spots.is_empty() {
            return;
        }
        self.changed = true;
        let dt = self.dt;
        for spot in &mut self.spots {
            spot.commit(&self.params, dt);
        }
        // Spots without power whose excess faded end (a NaN excess does not: the next
        // solve reports it).
        let mut k = self.spots.len();
        while k > 0 {
            k -= 1;
            let excess = self.spots[k].max_excess();
            if !self.spots[k].powered && excess.is_finite() && excess < RETIRE_KELVIN {
                self.retire(k);
            }
        }
    }

    /// Keeps `mark`, dropping the oldest beyond [`MAX_MARKS`].
    fn keep_mark(&mut self, mark: super::spot::BurnMark) {
        if self.marks.len() >= MAX_MARKS {
            self.marks.remove(0);
        }
        self.marks.push(mark);
    }

    /// Ends spot `k`: the excess heat of its tissue goes into the nodes where it lies; its
    /// volumes, boiled heat and the sensible heat of what vaporized are kept (with the
    /// heat the water took: they left as steam).
    fn retire(&mut self, k: usize) {
        let spot = self.spots.remove(k);
        let mut t = std::mem::take(&mut self.temperature);
        self.spread(&spot, &mut t);
        self.temperature = t;
        self.retired += spot.volumes(&self.params);
        self.retired_boiled += spot.boiled_energy() + spot.vaporized_sensible_energy();
        self.keep_mark(spot.mark());
    }

    /// Temperatures, peaks and damage at the samples after a step.
    pub(super) fn update_samples(&mut self) {
        if self.samples.is_empty() || !self.changed {
            return;
        }
        let s = self.params.meters_per_unit;
        let dt = self.dt;
        let p = self.params;
        for k in 0..self.samples.len() {
            let sample = &self.samples[k];
            let mut t = interpolate(&self.temperature, &sample.nodes);
            for spot in &self.spots {
                t += spot.excess_at(&sample.position, s);
            }
            self.sample_temperature[k] = t;
            if t > self.sample_peak[k] {
                self.sample_peak[k] = t;
            }
            if p.damage_frequency > 0.0 && t > p.damage_threshold {
                self.sample_damage[k] += dt * arrhenius(&p, t);
            }
        }
    }
}

/// Weights of a point: finite, at least 0 where `non_negative`, summing to 1 (to 1e-6).
fn check_weights(
    weights: impl Iterator<Item = (usize, f64)>,
    what: &'static str,
    non_negative: bool,
) -> Result<(), HeatError> {
    let mut sum = 0.0;
    for (node, w) in weights {
        if !w.is_finite() || (non_negative && w < 0.0) {
            return Err(HeatError::NonFinite {
                what,
                node,
                value: w,
            });
        }
        sum += w;
    }
    if (sum - 1.0).abs() > 1e-6 {
        return Err(HeatError::BadParameter {
            field: what,
            value: sum,
            expected: "summing to 1",
        });
    }
    Ok(())
}
