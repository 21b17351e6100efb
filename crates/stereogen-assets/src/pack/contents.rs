//! What the built-in content pack holds: pinned PyPI packages whose wheels ship real photos and
//! meshes, and the files taken from each with their licence and a SHA-256 of the exact bytes.
//!
//! Only content whose licence allows redistributing rendered images is listed. Looked at and left
//! out: scikit-image's `coins`, `ihc` ("no known copyright restrictions", no licence stated),
//! `moon`, `page`, `logo` (no statement), the Middlebury `motorcycle` pair; pybullet's
//! `pybullet_data` (103 MB wheel, models of mixed and mostly unstated origin); robosuite's
//! textures and objects (157 MB wheel, no per-file provenance); dm_control's arena textures (no
//! stated origin).

/// A pinned package of the pack.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PackPackage {
    /// The PyPI name.
    pub name: &'static str,
    pub version: &'static str,
    /// The package's own licence (each file states the licence it is used under).
    pub licence: &'static str,
}

/// Whether a pack file textures surfaces or is placed as an object.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "snake_case")]
pub enum PackKind {
    Photo,
    Mesh,
}

/// One file of the pack, as installed by pip (`--target`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PackFile {
    /// Index into [`PACKAGES`].
    pub package: usize,
    /// Path inside the install folder.
    pub path: &'static str,
    pub kind: PackKind,
    /// SPDX identifier (or `public-domain`) of the licence the file is used under.
    pub licence: &'static str,
    /// Who made it, where from, and where the licence is stated.
    pub source: &'static str,
    /// SHA-256 of the file as the pinned wheel ships it.
    pub sha256: &'static str,
}

const SKIMAGE: usize = 0;
const PYVISTA: usize = 1;
const DM_CONTROL: usize = 2;

pub const PACKAGES: &[PackPackage] = &[
    PackPackage {
        name: "scikit-image",
        version: "0.26.0",
        licence: "BSD-3-Clause",
    },
    PackPackage {
        name: "pyvista",
        version: "0.49.1",
        licence: "MIT",
    },
    PackPackage {
        name: "dm_control",
        version: "1.0.50",
        licence: "Apache-2.0",
    },
];

/// One entry of `FILES`: a photo or a mesh, from the package at index `package` of `PACKAGES`.
const fn pack_file(
    kind: PackKind,
    package: usize,
    path: &'static str,
    licence: &'static str,
    source: &'static str,
    sha256: &'static str,
) -> PackFile {
    PackFile {
        package,
        path,
        kind,
        licence,
        source,
        sha256,
    }
}

/// dm_control's dog model (DeepMind), under the package's Apache-2.0 licence.
const DOG: &str = "dm_control dog model (DeepMind), dm_control/suite/dog_assets";

/// scikit-image states each photo's licence in the docstring of its loader
/// (`skimage/data/_fetchers.py`); the `source` quotes it.
pub const FILES: &[PackFile] = &[
    pack_file(
        PackKind::Photo,
        SKIMAGE,
        "skimage/data/astronaut.png",
        "public-domain",
        "Eileen Collins, NASA; scikit-image: 'No known copyright restrictions, released into the public domain'",
        "88431cd9653ccd539741b555fb0a46b61558b301d4110412b5bc28b5e3ea6cb5",
    ),
    pack_file(
        PackKind::Photo,
        SKIMAGE,
        "skimage/data/brick.png",
        "CC0-1.0",
        "CC0Textures Bricks25; scikit-image: CC0",
        "7966caf324f6ba843118d98f7a07746d22f6a343430add0233eca5f6eaaa8fcf",
    ),
    pack_file(
        PackKind::Photo,
        SKIMAGE,
        "skimage/data/camera.png",
        "CC0-1.0",
        "Lav Varshney; scikit-image: CC0 by the photographer",
        "b0793d2adda0fa6ae899c03989482bff9a42d3d5690fc7e3648f2795d730c23a",
    ),
    pack_file(
        PackKind::Photo,
        SKIMAGE,
        "skimage/data/cell.png",
        "CC0-1.0",
        "Paul Müller et al.; scikit-image: CC0",
        "8d23a7fb81f7cc877cd09f330357fc7f595651306e84e17252f6e0a1b3f61515",
    ),
    pack_file(
        PackKind::Photo,
        SKIMAGE,
        "skimage/data/chelsea.png",
        "CC0-1.0",
        "Stefan van der Walt; scikit-image: CC0 by the photographer",
        "596aa1e7cb875eb79f437e310381d26b338a81c2da23439704a73c4651e8c4bb",
    ),
    pack_file(
        PackKind::Photo,
        SKIMAGE,
        "skimage/data/clock_motion.png",
        "public-domain",
        "Stefan van der Walt; scikit-image: released into the public domain by the photographer",
        "f029226b28b642e80113d86622e9b215ee067a0966feaf5e60604a1e05733955",
    ),
    pack_file(
        PackKind::Photo,
        SKIMAGE,
        "skimage/data/coffee.png",
        "CC0-1.0",
        "Rachel Michetti; scikit-image: CC0 by the photographer",
        "cc02f8ca188b167c775a7101b5d767d1e71792cf762c33d6fa15a4599b5a8de7",
    ),
    pack_file(
        PackKind::Photo,
        SKIMAGE,
        "skimage/data/grass.png",
        "CC0-1.0",
        "linolafett (DeviantArt) Grass-01; scikit-image: CC0",
        "b6b6022426b38936c43a4ac09635cd78af074e90f42ffa8227ac8b7452d39f89",
    ),
    pack_file(
        PackKind::Photo,
        SKIMAGE,
        "skimage/data/gravel.png",
        "CC0-1.0",
        "CC0Textures Gravel04; scikit-image: CC0",
        "c48615b451bf1e606fbd72c0aa9f8cc0f068ab7111ef7d93bb9b0f2586440c12",
    ),
    pack_file(
        PackKind::Photo,
        SKIMAGE,
        "skimage/data/hubble_deep_field.jpg",
        "public-domain",
        "NASA Hubble; scikit-image: 'may be freely used in the public domain'",
        "3a19c5dd8a927a9334bb1229a6d63711b1c0c767fb27e2286e7c84a3e2c2f5f4",
    ),
    pack_file(
        PackKind::Photo,
        SKIMAGE,
        "skimage/data/retina.jpg",
        "CC0-1.0",
        "Wikimedia Commons fundus photograph; scikit-image: CC0 1.0",
        "38a07f36f27f095e818aea7b96d34202c05176d30253c66733f2e00379e9e0e6",
    ),
    pack_file(
        PackKind::Photo,
        SKIMAGE,
        "skimage/data/rocket.jpg",
        "public-domain",
        "SpaceX DSCOVR launch; scikit-image: released in the public domain by SpaceX",
        "c2dd0de7c538df8d111e479619b129464d0269d0ae5fd18ca91d33a7fdfea95c",
    ),
    pack_file(
        PackKind::Photo,
        SKIMAGE,
        "skimage/data/text.png",
        "public-domain",
        "Wikipedia Corner.png; scikit-image: 'released into the public domain'",
        "bd84aa3a6e3c9887850d45d606c96b2e59433fbef50338570b63c319e668e6d1",
    ),
    pack_file(
        PackKind::Photo,
        PYVISTA,
        "pyvista/examples/2k_earth_daymap.jpg",
        "CC-BY-4.0",
        "Solar System Scope (solarsystemscope.com/textures), CC BY 4.0; shipped by pyvista",
        "767ee1dc6eb3802699bfccf6f264880f8acd0b80de3191cd24984fe279b07b7c",
    ),
    pack_file(
        PackKind::Mesh,
        PYVISTA,
        "pyvista/examples/airplane.ply",
        "MIT",
        "pyvista example mesh, shipped in its MIT-licensed wheel",
        "370846416b2d0d9c574e356a5b43c7aac2db748761daab270fdd1331f97305a8",
    ),
    pack_file(
        PackKind::Mesh,
        PYVISTA,
        "pyvista/examples/ant.ply",
        "MIT",
        "pyvista example mesh, shipped in its MIT-licensed wheel",
        "1e825c23c85588c9ea8d31b53e09791a6cd20fa9f835e98d4c61389e4209a73b",
    ),
    pack_file(
        PackKind::Mesh,
        PYVISTA,
        "pyvista/examples/nut.ply",
        "MIT",
        "pyvista example mesh, shipped in its MIT-licensed wheel",
        "51df5ca42ddbac9123e59678d532557278b11dee915274c98ea8897acc604c0a",
    ),
    pack_file(
        PackKind::Mesh,
        DM_CONTROL,
        "dm_control/suite/dog_assets/SKINbody.stl",
        "Apache-2.0",
        DOG,
        "4006bab0531668328f1527d23c925490249d55c19a293afff1ae89b8dd8a2209",
    ),
    pack_file(
        PackKind::Mesh,
        DM_CONTROL,
        "dm_control/suite/dog_assets/BONEMergedSkull.stl",
        "Apache-2.0",
        DOG,
        "f9672092ccfc7995b38c9ba54acba771d92d5a78df2a0d3bd35821652097a4d3",
    ),
    pack_file(
        PackKind::Mesh,
        DM_CONTROL,
        "dm_control/suite/dog_assets/BONEJaw.stl",
        "Apache-2.0",
        DOG,
        "0ce402a75106d72f2ad200c7f57572cf28d273c8e8b28f02d33150bbe22a548d",
    ),
    pack_file(
        PackKind::Mesh,
        DM_CONTROL,
        "dm_control/suite/dog_assets/BONERibcage.stl",
        "Apache-2.0",
        DOG,
        "161d56c0d2625ffcd694329f602e73ec59dbffb2ec8d25fa344bdca2ccaff316",
    ),
    pack_file(
        PackKind::Mesh,
        DM_CONTROL,
        "dm_control/suite/dog_assets/BONEPelvis.stl",
        "Apache-2.0",
        DOG,
        "588395a0abef1254722de551e7c11fa0b30f62aa426fb07d0f0ef06edf4a50fe",
    ),
    pack_file(
        PackKind::Mesh,
        DM_CONTROL,
        "dm_control/suite/dog_assets/BONESacrum.stl",
        "Apache-2.0",
        DOG,
        "ff3833d46bc3331e82102067c00ebcb04792a89bbcb4ce62e1a374e2a918b44f",
    ),
    pack_file(
        PackKind::Mesh,
        DM_CONTROL,
        "dm_control/suite/dog_assets/BONEScapula_L.stl",
        "Apache-2.0",
        DOG,
        "baba9e93ed01a83055ea6771afd1df0cc499d7313d1a82652c661071b1ad88b1",
    ),
    pack_file(
        PackKind::Mesh,
        DM_CONTROL,
        "dm_control/suite/dog_assets/BONEhumerus_L.stl",
        "Apache-2.0",
        DOG,
        "d52095023315579f46fe21e259ff12afd0457e224c546bd49269f39c3d21369d",
    ),
    pack_file(
        PackKind::Mesh,
        DM_CONTROL,
        "dm_control/suite/dog_assets/BONEFemoris_L.stl",
        "Apache-2.0",
        DOG,
        "c320fd52d5be9c4a4cbb9f6d180eeb77847e596417298e282aa6c494217a12c7",
    ),
    pack_file(
        PackKind::Mesh,
        DM_CONTROL,
        "dm_control/suite/dog_assets/BONETibia_L.stl",
        "Apache-2.0",
        DOG,
        "4f78bd55e650747f6109edd9a8e1f29270d372b00a5c107b5ce11cc02a431ea3",
    ),
    pack_file(
        PackKind::Mesh,
        DM_CONTROL,
        "dm_control/suite/dog_assets/BONEUlna_L.stl",
        "Apache-2.0",
        DOG,
        "08bb89317a4ae76eb565ff84407ab60d5624217e121a459fcc0125915b7c5fb1",
    ),
    pack_file(
        PackKind::Mesh,
        DM_CONTROL,
        "dm_control/suite/dog_assets/BONEC_1.stl",
        "Apache-2.0",
        DOG,
        "edadd48785ca315f97182a133501376d6323a0c25c66c903dfc8a52044ee3f70",
    ),
    pack_file(
        PackKind::Mesh,
        DM_CONTROL,
        "dm_control/suite/dog_assets/BONEL_1.stl",
        "Apache-2.0",
        DOG,
        "1bdd61891b9d66b46c5a3a4242c72829dc91defefff4d78a6d67784e8d8b03d1",
    ),
];

/// The pip requirement of every package (`name==version`).
pub fn requirements() -> Vec<String> {
    PACKAGES
        .iter()
        .map(|p| format!("{}=={}", p.name, p.version))
        .collect()
}
