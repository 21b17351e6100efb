//! The search windows AGCL alternates over the refinement iterations.

/// The two search windows alternated over the iterations (even: row, odd: square).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SearchWindow {
    /// 1×9 horizontal window (the reference's `small_patch = False`).
    Row1x9,
    /// 3×3 window (the reference's `small_patch = True`).
    Square3x3,
}

impl SearchWindow {
    /// Window used at iteration `itr` of a level.
    pub fn for_iteration(itr: usize) -> Self {
        if itr.is_multiple_of(2) {
            SearchWindow::Row1x9
        } else {
            SearchWindow::Square3x3
        }
    }

    /// (ry, rx) half-extent.
    pub fn radius(self) -> (usize, usize) {
        match self {
            SearchWindow::Row1x9 => (0, 4),
            SearchWindow::Square3x3 => (1, 1),
        }
    }

    /// Integer offsets (dx, dy), dy outer, dx inner.
    pub fn offsets(self) -> Vec<(i64, i64)> {
        let (ry, rx) = self.radius();
        let (ry, rx) = (ry as i64, rx as i64);
        let mut v = Vec::new();
        for dy in -ry..=ry {
            for dx in -rx..=rx {
                v.push((dx, dy));
            }
        }
        v
    }
}
