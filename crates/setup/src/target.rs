//! The printed calibration target of the geometric calibration: a
//! checkerboard of `squares x squares` squares of `square_mm`, dark in the
//! square at its `-x, -y` corner, laid on the sample holder with its centre
//! on the sample's centre and its rows along the gantry's travel (`x`). Its
//! inner corners are the points the calibration finds in the image.

use glam::Vec2;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckerTarget {
    /// Squares per side (even: the board is the same after a half turn,
    /// which the camera's rough pose from the rig file resolves).
    pub squares: u32,
    pub square_mm: f32,
}

impl Default for CheckerTarget {
    /// 8 x 8 squares of 10 mm: 49 inner corners over the middle 60 mm of
    /// the default 100 mm sample.
    fn default() -> Self {
        Self { squares: 8, square_mm: 10.0 }
    }
}

impl CheckerTarget {
    /// Inner corners per side.
    pub fn corners_per_side(&self) -> u32 {
        self.squares.saturating_sub(1)
    }

    /// Inner corner `(i, j)` in the target's own frame (mm, centred): `i`
    /// along `x`, `j` along `y`, both from the `-x, -y` side.
    pub fn corner(&self, i: u32, j: u32) -> Vec2 {
        let half = 0.5 * self.squares as f32 * self.square_mm;
        Vec2::new(-half + (i + 1) as f32 * self.square_mm, -half + (j + 1) as f32 * self.square_mm)
    }

    /// Whether the print is dark at `p` (target frame, mm); outside the
    /// board it is the paper's white.
    pub fn is_dark(&self, p: Vec2) -> bool {
        let half = 0.5 * self.squares as f32 * self.square_mm;
        if p.x.abs() >= half || p.y.abs() >= half {
            return false;
        }
        let i = ((p.x + half) / self.square_mm).floor() as i64;
        let j = ((p.y + half) / self.square_mm).floor() as i64;
        (i + j) % 2 == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corners_sit_where_four_squares_meet() {
        let t = CheckerTarget::default();
        assert_eq!(t.corners_per_side(), 7);
        let c = t.corner(0, 0);
        assert_eq!(c, Vec2::new(-30.0, -30.0));
        let e = 0.1;
        // Diagonal neighbours share a colour, adjacent ones differ.
        assert!(t.is_dark(c + Vec2::new(-e, -e)) && t.is_dark(c + Vec2::new(e, e)));
        assert!(!t.is_dark(c + Vec2::new(e, -e)) && !t.is_dark(c + Vec2::new(-e, e)));
        assert!(!t.is_dark(Vec2::new(45.0, 0.0)), "the margin is white");
    }
}
