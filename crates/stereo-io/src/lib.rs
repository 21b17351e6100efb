//! The one place that reads and writes stereo data, for the generator, the trainer and Python.
//!
//! - Disparity: float32 EXR with validity and camera attributes ([`exr_io`]), PFM ([`pfm`]),
//!   16-bit PNG with a scale and Sintel's RGB packing ([`png_disp`]), NumPy `.npy` ([`npy`]);
//!   [`read_disparity`]/[`write_disparity`] pick the format from the file name.
//! - Images: 8/16-bit, grey/colour, PNG/JPEG ([`image_io`]); JPEG decoded and encoded by
//!   libjpeg-turbo's codec, bit-identical to PIL and OpenCV ([`jpeg`]).
//! - Datasets: ours and the public stereo sets behind one trait ([`datasets`]), each layout with
//!   its file names, reader and writer; our manifest and dataset description
//!   ([`datasets::stereogen`]; its types are re-exported here).
//!
//! Every reader names the file and the problem in its error; nothing here panics on bad input.

pub mod atomic;
pub mod colormap;
pub mod datasets;
pub mod digest;
pub mod disparity;
pub mod error;
pub mod exr_io;
pub mod formats;
pub mod image_io;
mod images;
pub mod jpeg;
pub mod limits;
pub mod maps;
pub mod npy;
pub mod pfm;
pub mod pixel_coords;
pub mod png_disp;
pub mod pth;

pub use atomic::{is_temp_name, temp_sibling, write_atomically, write_bytes_atomically};
pub use datasets::export::create_writer;
pub use datasets::export::{ExportOptions, SampleSelection, export_dataset, export_selected};
pub use datasets::middlebury::MiddleburyVariant;
pub use datasets::stereogen::{
    DatasetInfo, DatasetLayout, DisparitySummary, Manifest, ManifestContents, ManifestEntry,
    SamplePaths, read_manifest,
};
pub use datasets::webdataset::{
    WebDataset, WebDatasetOptions, WebDatasetSummary, export_webdataset,
    export_webdataset_selected, parse_splits,
};
pub use datasets::write::{DatasetWriter, ImageEncoding, WritableFormat, WriteSummary};
pub use datasets::{
    DatasetFormat, ReadOptions, SampleMeta, StereoDataset, StereoSample, detect_format,
    open_dataset, open_dataset_with,
};
pub use disparity::{DisparityMap, DisparityMeta, DisparityStats, LEFT_RIGHT_TOLERANCE_PX};
pub use error::{Error, Result};
pub use exr_io::{
    RenderPasses, decode_disparity_exr, read_depth_channel, read_disparity_exr, read_render_passes,
    write_disparity_exr,
};
pub use formats::{DisparityFormat, read_disparity, write_disparity};
pub use image_io::{
    Image, RgbImage, Samples, read_image, read_rgb, write_jpeg_rgb, write_png, write_png_rgb,
};
pub use jpeg::{ChromaSampling, JpegOptions, decode_jpeg, encode_jpeg_rgb, write_jpeg};
pub use maps::{
    DepthMap, IdMap, MapKind, NormalMap, read_depth_exr, read_id_png, read_normals_exr,
    write_depth_exr, write_id_png, write_normals_exr,
};
pub use npy::{NpyArray, read_disparity_npy, read_npy, read_npz, write_disparity_npy, write_npy};
pub use pfm::{
    Endian, FloatImage, decode_pfm, read_disparity_pfm, read_pfm, write_disparity_pfm, write_pfm,
};
pub use png_disp::{
    CRESTEREO_SCALE, KITTI_SCALE, decode_disparity_png16, read_disparity_png16,
    read_disparity_sintel, write_disparity_png16, write_disparity_sintel,
};
