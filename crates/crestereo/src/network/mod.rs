//! The network, top-down as the reference reads: the feature encoder, the LoFTR-style attention
//! and its position encoding, the adaptive group correlation, the update block (motion encoder
//! and SepConvGRU), one level's refinement, and the model that cascades the levels.

pub mod attention;
pub mod corr;
pub mod encoder;
pub(crate) mod formula;
pub mod gru;
pub(crate) mod level;
pub mod model;
pub mod motion_encoder;
pub mod observer;
pub mod position_encoding;
pub mod refine;
pub mod update;
