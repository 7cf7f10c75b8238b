//! `[plant]`: the robot a schema server drives in simulation (the end-effector, the plate, its
//! holes and parts, the obstacles), read into a [`PlantConfig`] in the board's units (µm).
//!
//! The configuration is part of the network model, like every section of the file; the plant's
//! physics that steps it belongs to the simulator (`crate::sim::plant`).

use super::spanned::Spanned;
use schemars::JsonSchema;
use serde::Deserialize;

use super::{Builder, SchemaBoard, list_or_none};

/// A box the tip cannot enter (µm): an obstacle on the way.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Obstacle {
    /// Lower corner (x, y, z), µm.
    pub min: [f64; 3],
    /// Upper corner, µm.
    pub max: [f64; 3],
}

/// The plant's geometry and physics. Lengths µm, as the board's.
#[derive(Clone, Debug, PartialEq)]
pub struct PlantConfig {
    /// The moving mass, kg.
    pub mass_kg: f64,
    /// N/m.
    pub contact_stiffness: f64,
    /// N·s/m.
    pub contact_damping: f64,
    /// µm.
    pub part_height: f64,
    /// µm.
    pub part_half_width: f64,
    /// µm: the hole is this much wider than the part on each side.
    pub clearance: f64,
    /// µm.
    pub hole_depth: f64,
    /// How far the part's centre may be from the tip for a grasp to take it, µm.
    pub grasp_tolerance: f64,
    /// How deep in its hole a released part counts as inserted, µm.
    pub insert_depth: f64,
    /// The parts' centres on the plate (x, y), µm.
    pub parts: Vec<[f64; 2]>,
    /// The holes' centres (x, y), µm: where they really are.
    pub holes: Vec<[f64; 2]>,
    /// Boxes in the way.
    pub obstacles: Vec<Obstacle>,
    /// The tip's position at the start, µm.
    pub start: [f64; 3],
    /// The board sensor (its index) the range finder's readings go to, if any.
    pub range_finder: Option<usize>,
}

impl Default for PlantConfig {
    /// The paper's assembly: 15 mm parts, ±0.05 mm clearance, a 2 kg arm; no parts or holes.
    fn default() -> Self {
        PlantConfig {
            mass_kg: 2.0,
            contact_stiffness: 200_000.0,
            contact_damping: 400.0,
            part_height: 15_000.0,
            part_half_width: 10_000.0,
            clearance: 50.0,
            hole_depth: 15_000.0,
            grasp_tolerance: 2_000.0,
            insert_depth: 1_000.0,
            parts: Vec::new(),
            holes: Vec::new(),
            obstacles: Vec::new(),
            start: [0.0, 0.0, 50_000.0],
            range_finder: None,
        }
    }
}

/// `[plant]`.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawPlant {
    /// The tip at the start, [x, y, z] in mm, default [0, 0, 50].
    start_mm: Option<Spanned<Vec<f64>>>,
    /// The moving mass, kg, default 2.
    mass_kg: Option<Spanned<f64>>,
    /// Its contacts' stiffness, N/m, default 200000.
    contact_stiffness_n_per_m: Option<Spanned<f64>>,
    /// Its contacts' damping, N·s/m, default 400.
    contact_damping_ns_per_m: Option<Spanned<f64>>,
    /// The parts' height, mm, default 15.
    part_height_mm: Option<Spanned<f64>>,
    /// Half the parts' width, mm (default 10).
    part_half_width_mm: Option<Spanned<f64>>,
    /// The holes are as wide as a part plus this on each side, mm, default 0.05 (no
    /// chamfer).
    clearance_mm: Option<Spanned<f64>>,
    /// The holes' depth, mm, default 15.
    hole_depth_mm: Option<Spanned<f64>>,
    /// A grasp takes the part whose centre is this near the tip, mm, default 2.
    grasp_tolerance_mm: Option<Spanned<f64>>,
    /// A part released this deep in a hole is inserted, mm, default 1.
    insert_depth_mm: Option<Spanned<f64>>,
    /// Where the parts stand, [x, y] in mm each.
    #[serde(default)]
    parts_mm: Vec<Spanned<Vec<f64>>>,
    /// Where the holes really are, [x, y] in mm each.
    #[serde(default)]
    holes_mm: Vec<Spanned<Vec<f64>>>,
    /// Boxes in the way.
    #[serde(default)]
    obstacles: Vec<Spanned<RawObstacle>>,
    /// Optional: a sensor of `[schema.NODE]` (unit = "mm") on which the plant publishes its
    /// range finder.
    range_finder: Option<Spanned<String>>,
}

/// `{ min_mm = [-110, -10, 0], max_mm = [-90, 10, 60] }`: a box in the way.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawObstacle {
    /// Required: its lowest x, y, z, mm.
    min_mm: Spanned<Vec<f64>>,
    /// Required: its highest x, y, z, mm.
    max_mm: Spanned<Vec<f64>>,
}

impl Builder<'_> {
    pub(super) fn plant(
        &mut self,
        raw: Option<&Spanned<RawPlant>>,
        boards: &[SchemaBoard],
    ) -> Option<PlantConfig> {
        let raw = raw?.get_ref();
        let errors = self.errors.len();
        let mut plant = PlantConfig::default();
        let positive =
            |b: &mut Self, v: &Option<Spanned<f64>>, scale: f64, what: &str, out: &mut f64| {
                if let Some(v) = v {
                    let x = *v.get_ref() * scale;
                    if x.is_finite() && x > 0.0 && x <= 1e12 {
                        *out = x;
                    } else {
                        b.error(v.span(), format!("{what} must be a positive number"));
                    }
                }
            };
        positive(self, &raw.mass_kg, 1.0, "mass_kg", &mut plant.mass_kg);
        positive(
            self,
            &raw.contact_stiffness_n_per_m,
            1.0,
            "contact_stiffness_n_per_m",
            &mut plant.contact_stiffness,
        );
        positive(
            self,
            &raw.contact_damping_ns_per_m,
            1.0,
            "contact_damping_ns_per_m",
            &mut plant.contact_damping,
        );
        positive(
            self,
            &raw.part_height_mm,
            1000.0,
            "part_height_mm",
            &mut plant.part_height,
        );
        positive(
            self,
            &raw.part_half_width_mm,
            1000.0,
            "part_half_width_mm",
            &mut plant.part_half_width,
        );
        positive(
            self,
            &raw.clearance_mm,
            1000.0,
            "clearance_mm",
            &mut plant.clearance,
        );
        positive(
            self,
            &raw.hole_depth_mm,
            1000.0,
            "hole_depth_mm",
            &mut plant.hole_depth,
        );
        positive(
            self,
            &raw.grasp_tolerance_mm,
            1000.0,
            "grasp_tolerance_mm",
            &mut plant.grasp_tolerance,
        );
        positive(
            self,
            &raw.insert_depth_mm,
            1000.0,
            "insert_depth_mm",
            &mut plant.insert_depth,
        );
        if let Some(start) = &raw.start_mm
            && let Some(p) = self.point(start, "start_mm", 3)
        {
            plant.start = [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])];
        }
        for (list, out, what) in [
            (&raw.parts_mm, &mut plant.parts, "parts_mm"),
            (&raw.holes_mm, &mut plant.holes, "holes_mm"),
        ] {
            for xy in list {
                match xy.get_ref().as_slice() {
                    [x, y] if x.is_finite() && y.is_finite() => out.push([x * 1000.0, y * 1000.0]),
                    _ => self.error(xy.span(), format!("{what}: each entry is [x, y] in mm")),
                }
            }
        }
        for o in &raw.obstacles {
            let min = self.point(&o.get_ref().min_mm, "min_mm", 3);
            let max = self.point(&o.get_ref().max_mm, "max_mm", 3);
            if let (Some(min), Some(max)) = (min, max) {
                if min.iter().zip(&max).take(3).any(|(lo, hi)| lo >= hi) {
                    self.error(
                        o.span(),
                        "an obstacle's min_mm must be below its max_mm on every axis",
                    );
                }
                plant.obstacles.push(Obstacle {
                    min: [0, 1, 2].map(|i| f64::from(min[i])),
                    max: [0, 1, 2].map(|i| f64::from(max[i])),
                });
            }
        }
        if let Some(name) = &raw.range_finder {
            let sensors = boards.first().map_or(&[][..], |b| b.sensors.as_slice());
            match sensors.iter().position(|s| &s.name == name.get_ref()) {
                Some(i) if sensors[i].unit == "mm" => plant.range_finder = Some(i),
                Some(_) => self.error(
                    name.span(),
                    format!(
                        "range_finder: sensor `{}` must have unit = \"mm\": the plant publishes mm",
                        name.get_ref()
                    ),
                ),
                None => {
                    let known: Vec<&str> = sensors.iter().map(|s| s.name.as_str()).collect();
                    self.error(
                        name.span(),
                        format!(
                            "range_finder: `{}` is not a sensor of the schema server (sensors: {})",
                            name.get_ref(),
                            list_or_none(&known)
                        ),
                    );
                }
            }
        }
        (self.errors.len() == errors).then_some(plant)
    }
}
