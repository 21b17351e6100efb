//! Adaptive Group Correlation Layer (AGCL).
//!
//! Features are split into `groups` channel groups; for every group and every search candidate
//! the correlation is the mean over the group's channels of `left · right(candidate)`.
//! Candidates alternate between a 1×9 row (dx = −4..4) and a 3×3 square, dilation 1, ordered
//! row-major (dy outer, dx inner). Output channel `g·9 + k` = group `g`, candidate `k`.
//!
//! * 1/16 and 1/8 ([`AdaptiveGroupCorrelation::corr_offset`]): each candidate is bilinearly
//!   sampled at `grid + flow + window offset + learned offset` (zero padding).
//! * 1/4 ([`AdaptiveGroupCorrelation::corr_warp`]): the right map is warped once by the flow,
//!   replicate-padded and shifted by the integer window offsets.

use burn::prelude::*;

use crate::network::attention::{LoFTREncoderLayer, to_tokens};
use crate::ops::agcl::CorrSpec;
pub use crate::ops::agcl::SearchWindow;

#[derive(Config, Debug)]
pub struct AdaptiveGroupCorrelationConfig {
    #[config(default = 4)]
    pub groups: usize,
}

/// Correlation state for one pyramid level: the left / right feature maps (N, C, H, W).
#[derive(Clone, Debug)]
pub struct AdaptiveGroupCorrelation<B: Backend> {
    pub fmap1: Tensor<B, 4>,
    pub fmap2: Tensor<B, 4>,
    pub groups: usize,
}

impl AdaptiveGroupCorrelationConfig {
    pub fn init<B: Backend>(
        &self,
        fmap1: Tensor<B, 4>,
        fmap2: Tensor<B, 4>,
    ) -> AdaptiveGroupCorrelation<B> {
        assert_eq!(
            fmap1.dims(),
            fmap2.dims(),
            "AGCL: left/right feature shapes differ"
        );
        assert!(
            fmap1.dims()[1].is_multiple_of(self.groups),
            "AGCL: channels not divisible by groups"
        );
        AdaptiveGroupCorrelation {
            fmap1,
            fmap2,
            groups: self.groups,
        }
    }
}

impl<B: Backend> AdaptiveGroupCorrelation<B> {
    /// The 1/16 cross-attention step: left attends right, then right attends the updated left.
    /// Returns the attended maps as tokens (N, H·W, C).
    pub fn cross_attend(&self, layer: &LoFTREncoderLayer<B>) -> (Tensor<B, 3>, Tensor<B, 3>) {
        layer.forward_cross(to_tokens(self.fmap1.clone()), to_tokens(self.fmap2.clone()))
    }

    /// Offset correlation of this level's own maps (1/8; at 1/16 the maps are cross-attended
    /// first, see [`Self::cross_attend`] and [`Self::corr_offset_maps`]).
    ///
    /// `flow`: (N, 2, H, W) (x, y); `extra_offset`: (N, 18, H, W), channel `2k` = x and `2k+1` = y
    /// offset of candidate `k`. Returns (N, groups·9, H, W).
    pub fn corr_offset(
        &self,
        flow: Tensor<B, 4>,
        extra_offset: Tensor<B, 4>,
        window: SearchWindow,
    ) -> Tensor<B, 4> {
        self.corr_offset_maps(
            self.fmap1.clone(),
            self.fmap2.clone(),
            flow,
            extra_offset,
            window,
        )
    }

    /// Offset correlation between explicit `left` / `right` maps of this level's shape.
    pub fn corr_offset_maps(
        &self,
        left: Tensor<B, 4>,
        right: Tensor<B, 4>,
        flow: Tensor<B, 4>,
        extra_offset: Tensor<B, 4>,
        window: SearchWindow,
    ) -> Tensor<B, 4> {
        crate::ops::agcl::offset_corr(
            left,
            right,
            flow,
            extra_offset,
            CorrSpec::new(window, self.groups),
        )
    }

    /// Warp-and-shift correlation used at 1/4 (no learned offsets).
    pub fn corr_warp(&self, flow: Tensor<B, 4>, window: SearchWindow) -> Tensor<B, 4> {
        let warped = crate::ops::agcl::warp(self.fmap2.clone(), flow);
        crate::ops::agcl::shift_corr(
            self.fmap1.clone(),
            warped,
            CorrSpec::new(window, self.groups),
        )
    }
}
