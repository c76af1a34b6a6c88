//! The capture plan: which gantry positions, which LEDs, which exposures,
//! and how many dark frames. Shots are ordered step by step, exposure by
//! exposure within a step (an exposure change costs dropped frames), LED by
//! LED within an exposure.

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::geometry::RigGeometry;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CapturePlan {
    /// Number of gantry positions.
    pub steps: u32,
    /// First and last bar position (inclusive), millimetres.
    pub first_mm: f32,
    pub last_mm: f32,
    /// LEDs fired at each position.
    pub leds: Vec<u8>,
    /// Exposure times of the HDR bracket, longest first (one entry = no HDR).
    pub exposures_us: Vec<u32>,
    /// Analog gain.
    pub gain: f32,
    /// Dark frames (all LEDs off) taken per exposure before the shots.
    pub dark_frames: u32,
    /// Which of the bracket's shorter exposures are taken (plans written
    /// before adaptive brackets took every one).
    #[serde(default)]
    pub bracket: Bracket,
}

/// Which shots of an HDR bracket a capture takes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Bracket {
    /// Every exposure of every light.
    #[default]
    Every,
    /// A light's next shorter exposure only where its longer one clipped
    /// on the sample (module docs).
    Clipped,
}

impl std::str::FromStr for Bracket {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "every" => Ok(Self::Every),
            "clipped" => Ok(Self::Clipped),
            _ => Err(format!("unknown bracket '{s}': use every or clipped")),
        }
    }
}

#[derive(Debug, Error, PartialEq)]
pub enum PlanError {
    #[error("the plan needs at least one step, one LED and one exposure")]
    Empty,
    #[error("LED {led} does not exist: the bar has {n} LEDs (0..{n})")]
    NoSuchLed { led: u8, n: u8 },
    #[error("bar position {mm} mm is outside the gantry's travel {min}..{max} mm")]
    OutOfTravel { mm: f32, min: f32, max: f32 },
    #[error("exposure {us} us is not usable (must be 10..=1000000 us)")]
    BadExposure { us: u32 },
}

/// One frame of the plan.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct PlannedShot {
    /// Dense index over all shots.
    pub index: u32,
    pub step: u32,
    pub led: u8,
    /// Index into `exposures_us`.
    pub exposure: u8,
    pub position_um: i32,
}

impl CapturePlan {
    /// The least time the rig can take this plan in, seconds: every frame
    /// (dark frames and shots) at the camera's frame period `1 / fps` (or
    /// its exposure, if longer), and every move between steps with its
    /// settling. Homing and calibration are outside it, and so are the
    /// shorter exposures of an adaptive bracket, which depend on the sample.
    pub fn physical_seconds(&self, g: &RigGeometry, fps: f32) -> f64 {
        let period = 1.0 / (fps as f64).max(1e-9);
        let frame = |us: u32| period.max(us as f64 * 1e-6);
        let bracketed = match self.bracket {
            Bracket::Every => self.exposures_us.len(),
            Bracket::Clipped => 1,
        };
        let per_light: f64 = self.exposures_us.iter().take(bracketed).map(|&us| frame(us)).sum();
        let darks: f64 = self.exposures_us.iter().map(|&us| self.dark_frames as f64 * frame(us)).sum();
        let step_mm = if self.steps > 1 { (self.last_mm - self.first_mm) / (self.steps - 1) as f32 } else { 0.0 };
        let moves =
            self.steps.saturating_sub(1) as f64 * (g.gantry.move_seconds(step_mm) + g.gantry.settle_ms as f64 / 1000.0);
        darks + self.n_lights() as f64 * per_light + moves
    }

    /// The design's full plan: 64 steps over the whole travel, all 40 LEDs,
    /// one exposure.
    pub fn full(geometry: &RigGeometry) -> Self {
        Self {
            steps: 64,
            first_mm: geometry.gantry.travel_min_mm,
            last_mm: geometry.gantry.travel_max_mm,
            leds: (0..geometry.bar.n_leds).collect(),
            exposures_us: vec![20_000],
            gain: 1.0,
            dark_frames: 8,
            bracket: Bracket::Every,
        }
    }

    pub fn validate(&self, g: &RigGeometry) -> Result<(), PlanError> {
        if self.steps == 0 || self.leds.is_empty() || self.exposures_us.is_empty() {
            return Err(PlanError::Empty);
        }
        if let Some(&led) = self.leds.iter().find(|&&l| l >= g.bar.n_leds) {
            return Err(PlanError::NoSuchLed { led, n: g.bar.n_leds });
        }
        for mm in [self.first_mm, self.last_mm] {
            if mm < g.gantry.travel_min_mm || mm > g.gantry.travel_max_mm || !mm.is_finite() {
                return Err(PlanError::OutOfTravel { mm, min: g.gantry.travel_min_mm, max: g.gantry.travel_max_mm });
            }
        }
        if let Some(&us) = self.exposures_us.iter().find(|&&e| !(10..=1_000_000).contains(&e)) {
            return Err(PlanError::BadExposure { us });
        }
        Ok(())
    }

    /// Bar position of step `s`, millimetres.
    pub fn step_mm(&self, s: u32) -> f32 {
        if self.steps <= 1 {
            return 0.5 * (self.first_mm + self.last_mm);
        }
        self.first_mm + (self.last_mm - self.first_mm) * s as f32 / (self.steps - 1) as f32
    }

    pub fn step_um(&self, s: u32) -> i32 {
        (self.step_mm(s) * 1000.0).round() as i32
    }

    /// Number of light positions (steps x LEDs), the fitter's "lights".
    pub fn n_lights(&self) -> usize {
        self.steps as usize * self.leds.len()
    }

    /// Light index of a (step, LED) pair.
    pub fn light_index(&self, step: u32, led: u8) -> Option<usize> {
        let k = self.leds.iter().position(|&l| l == led)?;
        Some(step as usize * self.leds.len() + k)
    }

    pub fn shots(&self) -> Vec<PlannedShot> {
        let mut v = Vec::with_capacity(self.n_lights() * self.exposures_us.len());
        for s in 0..self.steps {
            for e in 0..self.exposures_us.len() {
                for &led in &self.leds {
                    v.push(PlannedShot {
                        index: v.len() as u32,
                        step: s,
                        led,
                        exposure: e as u8,
                        position_um: self.step_um(s),
                    });
                }
            }
        }
        v
    }

    /// The shot of the same light at the next longer exposure, by index
    /// (`None` for a light's first, longest exposure).
    pub fn longer(&self, shot: &PlannedShot) -> Option<u32> {
        (shot.exposure > 0).then(|| shot.index - self.leds.len() as u32)
    }

    /// Whether `shot` is to be taken, given whether each shot (by index)
    /// clipped on the sample: `Some(true)` or `Some(false)` once known,
    /// `None` before it is taken. A shot whose longer exposure is not yet
    /// known to be clean is wanted.
    pub fn wants(&self, shot: &PlannedShot, clipped: impl Fn(u32) -> Option<bool>) -> bool {
        match (self.bracket, self.longer(shot)) {
            (Bracket::Every, _) | (_, None) => true,
            (Bracket::Clipped, Some(k)) => clipped(k).unwrap_or(true),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shots_cover_every_light_and_exposure_once() {
        let g = RigGeometry::default();
        let mut p = CapturePlan::full(&g);
        p.exposures_us = vec![20_000, 2_500];
        p.validate(&g).unwrap();
        let shots = p.shots();
        assert_eq!(shots.len(), 64 * 40 * 2);
        assert_eq!(shots[0].position_um, -120_000);
        assert_eq!(shots.last().unwrap().position_um, 120_000);
        assert_eq!(p.light_index(63, 39), Some(64 * 40 - 1));
        p.leds.push(40);
        assert!(matches!(p.validate(&g), Err(PlanError::NoSuchLed { .. })));
    }

    /// Frames at the frame period plus trapezoidal moves with settling,
    /// worked by hand for the default gantry (100 mm/s, 1,000 mm/s^2,
    /// 30 ms settling: full speed after 10 mm of ramps).
    #[test]
    fn the_physical_time_is_frames_and_moves() {
        let g = RigGeometry::default();
        assert_eq!((g.gantry.speed_mm_s, g.gantry.accel_mm_s2, g.gantry.settle_ms), (100.0, 1000.0, 30.0));
        let mut p = CapturePlan {
            steps: 2,
            first_mm: -120.0,
            last_mm: 120.0,
            leds: vec![0, 1],
            exposures_us: vec![20_000],
            gain: 1.0,
            dark_frames: 3,
            bracket: Bracket::Every,
        };
        // 3 darks + 4 shots at 0.1 s; one 240 mm move: 2.4 s + 0.1 s of
        // ramps, then 0.03 s settling.
        assert!((p.physical_seconds(&g, 10.0) - (0.7 + 2.5 + 0.03)).abs() < 1e-9);
        // A 4 mm move never reaches full speed: 2 sqrt(4 / 1000) s.
        p.first_mm = 0.0;
        p.last_mm = 4.0;
        assert!((p.physical_seconds(&g, 10.0) - (0.7 + 2.0 * 0.004f64.sqrt() + 0.03)).abs() < 1e-9);
        // An exposure longer than the frame period sets the pace.
        p.exposures_us = vec![250_000];
        assert!((p.physical_seconds(&g, 10.0) - (7.0 * 0.25 + 2.0 * 0.004f64.sqrt() + 0.03)).abs() < 1e-9);
        // An adaptive bracket's shorter exposures are not counted, but
        // their dark frames are.
        p.exposures_us = vec![250_000, 200_000];
        p.bracket = Bracket::Clipped;
        assert!((p.physical_seconds(&g, 10.0) - (7.0 * 0.25 + 0.6 + 2.0 * 0.004f64.sqrt() + 0.03)).abs() < 1e-9);
    }

    /// An adaptive bracket wants a light's shorter exposure exactly when
    /// its longer one clipped or is not known yet; a whole bracket wants
    /// every shot.
    #[test]
    fn an_adaptive_bracket_follows_the_longer_exposure() {
        let g = RigGeometry::default();
        let mut p = CapturePlan::full(&g);
        p.steps = 2;
        p.leds = vec![3, 7];
        p.exposures_us = vec![20_000, 2_500, 312];
        let shots = p.shots();
        // Step 0: LEDs 3 and 7 at each exposure in turn.
        assert_eq!(p.longer(&shots[0]), None);
        assert_eq!(p.longer(&shots[2]), Some(0));
        assert_eq!(p.longer(&shots[5]), Some(3));
        assert_eq!((shots[5].led, shots[3].led, shots[5].exposure), (7, 7, 2));
        // Shot 0 (LED 3, longest) clipped, shot 1 (LED 7) did not, shot 2
        // (LED 3 shorter) did not, shot 3 is not known.
        let seen = |k: u32| [Some(true), Some(false), Some(false), None].get(k as usize).copied().flatten();
        let wanted = |p: &CapturePlan| shots.iter().take(6).map(|s| p.wants(s, seen)).collect::<Vec<_>>();
        assert_eq!(wanted(&p), vec![true; 6]);
        p.bracket = Bracket::Clipped;
        assert_eq!(wanted(&p), vec![true, true, true, false, false, true]);
    }
}
