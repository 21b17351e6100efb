//! What to render: recipes, the seed tree, and the pure-data `SceneSpec` that the Blender worker obeys.
//!
//! Nothing here touches Blender; a scene is a pure function of (recipe, asset index, seed, index).

pub mod dist;
pub mod recipe;
pub mod rig;
pub mod rng;
pub mod sampler;
pub mod shapes;
pub mod spec;
pub mod tree;

pub use dist::Dist;
pub use recipe::{Recipe, RecipeError};
pub use rig::StereoRig;
pub use rng::SeedTree;
pub use sampler::{plan_scene, scene_category};
pub use spec::{BaseColor, LightSpec, MaterialClass, MaterialSpec, Modifier, ObjectRole, ObjectSpec, Pattern, RenderSettings, SceneSpec, Shape, WorldSpec};
