//! The cascade's levels, named by their resolution.

/// A level of the cascade, by its resolution relative to the input images.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Level {
    Sixteenth,
    Eighth,
    Quarter,
}

impl Level {
    /// The further upsampling from a convex-upsampled flow of this level (×rate, i.e. 1/4, 1/2
    /// or full resolution) to a full-resolution prediction.
    pub fn full_resolution_factor(self) -> usize {
        match self {
            Level::Sixteenth => 4,
            Level::Eighth => 2,
            Level::Quarter => 1,
        }
    }
}
