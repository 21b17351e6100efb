//! What to render: recipes, the seed tree, and the pure-data `SceneSpec` that the Blender worker obeys.
//!
//! Nothing here touches Blender or the file system; a scene is a pure function of (recipe, asset
//! index, seed, index). The asset index is plain data (`stereogen-assets` fills it from folders).

pub mod assets;
pub mod backgrounds;
pub mod checker;
pub mod dist;
pub mod photo_sizing;
pub mod recipe;
pub mod render;
pub mod rig;
pub mod rng;
pub mod sampler;
pub mod shapes;
pub mod spec;
pub mod tree;

pub use assets::{AssetIndex, MeshAsset, SkippedAsset, TextureAsset};
pub use backgrounds::BackgroundKind;
pub use checker::Violation;
pub use checker::scene_spec::check_scene_spec;
pub use dist::Dist;
pub use recipe::{Recipe, RecipeError};
pub use render::OutputMap;
pub use rig::{StereoCameras, StereoRig};
pub use rng::SeedTree;
pub use sampler::{plan_scene, scene_category};
pub use spec::{
    BaseColor, HdriSpec, LightSpec, MaterialClass, MaterialSpec, Modifier, ObjectRole, ObjectSpec,
    Pattern, RenderSettings, SEMANTIC_CLASSES, STUDIO_HDRIS, SceneSpec, Shape, SkySpec, WorldSpec,
};
