//! What to render: recipes, the seed tree, and the pure-data `SceneSpec` that the Blender worker obeys.
//!
//! Nothing here touches Blender; a scene is a pure function of (recipe, seed, index).

pub mod recipe;
pub mod rig;
pub mod rng;
pub mod sampler;
pub mod spec;

pub use recipe::{Recipe, RecipeError};
pub use rig::StereoRig;
pub use rng::SeedTree;
pub use sampler::plan_scene;
pub use spec::{LightSpec, MaterialSpec, ObjectSpec, Pattern, RenderSettings, SceneSpec, Shape, WorldSpec};
