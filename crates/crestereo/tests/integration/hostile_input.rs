//! What the network reads from outside, hostile: a `.pth` whose record claims 3 GB, Burn records
//! whose tensors disagree with their bytes or with the network, images and ONNX sizes over the
//! network's limit. Each is one error naming the file or the limit; nothing panics and nothing
//! is allocated for what the file claims.

use crate::network_fixtures;
use crestereo::infer::{InferenceOptions, MAX_INPUT_SIDE, check_input_size, infer_disparity};
use crestereo::weights::{load_pytorch, load_record, save_record};
use crestereo::{BgrImage, CREStereoConfig, CpuBackend};
use network_fixtures::*;

use crate::zip_edit;
type B = CpuBackend;

#[test]
fn a_pth_record_claiming_3_gb_is_refused_before_burn_reads_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("hostile.pth");
    let mut bytes = std::fs::read(fixtures().join("weights_seed0.pt")).unwrap();
    zip_edit::set_stated_size(&mut bytes, "weights_seed0/data/0", 3_000_000_000);
    std::fs::write(&path, &bytes).unwrap();
    let mut m = CREStereoConfig::new().init::<B>(&Default::default());
    let e = format!("{:#}", load_pytorch(&mut m, &path, false).unwrap_err());
    assert!(
        e.contains("hostile.pth") && e.contains("over the limit of 1 GiB"),
        "{e}"
    );
}

/// The byte offset of the `shape` array of the first tensor in a record.
fn first_shape(bytes: &[u8]) -> usize {
    // fixstr "shape" then a fixarray of 4 dimensions (the first parameter is a conv weight).
    let key = b"\xa5shape\x94";
    bytes.windows(key.len()).position(|w| w == key).unwrap() + key.len()
}

#[test]
fn burn_records_whose_tensors_disagree_are_refused_before_burn_decodes_them() {
    let device = Default::default();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("model");
    let fresh = || CREStereoConfig::new().init::<B>(&device);
    let file = save_record(&fresh(), &path).unwrap();
    let good = std::fs::read(&file).unwrap();
    let at = first_shape(&good);
    let dims = &good[at..at + 4];
    assert!(dims.iter().all(|&d| d < 0x80), "small dims: {dims:?}");

    // One dimension one larger: the shape asks for more bytes than the tensor holds (Burn
    // would stop the process in an assertion).
    let mut bytes = good.clone();
    bytes[at] += 1;
    std::fs::write(&file, &bytes).unwrap();
    let e = format!("{:#}", load_record(fresh(), &path, &device).unwrap_err());
    assert!(e.contains("model.mpk") && e.contains("it holds"), "{e}");

    // Two dimensions swapped: the bytes agree, the network's parameter does not (Burn would load
    // it and fail inside the forward pass).
    let mut bytes = good.clone();
    bytes.swap(at, at + 1);
    assert_ne!(bytes, good);
    std::fs::write(&file, &bytes).unwrap();
    let e = format!("{:#}", load_record(fresh(), &path, &device).unwrap_err());
    assert!(e.contains("the network's is"), "{e}");

    // Cut short.
    std::fs::write(&file, &good[..good.len() / 2]).unwrap();
    let e = format!("{:#}", load_record(fresh(), &path, &device).unwrap_err());
    assert!(e.contains("model.mpk"), "{e}");
}

#[test]
fn images_and_export_sizes_over_the_networks_limit_are_refused_up_front() {
    assert!(check_input_size(1920, 1088).is_ok());
    let e = check_input_size(30000, 30000).unwrap_err().to_string();
    assert!(
        e.contains("30000x30000") && e.contains("network's limit"),
        "{e}"
    );
    // A pair one pixel wider than the limit: refused before a tensor is made of it.
    let device = Default::default();
    let wide = BgrImage::from_rgb(&stereo_io::RgbImage {
        width: MAX_INPUT_SIDE + 1,
        height: 16,
        data: vec![0; (MAX_INPUT_SIDE + 1) * 16 * 3],
    });
    let model = CREStereoConfig::new().init::<B>(&device);
    let e = infer_disparity(&model, &wide, &wide, InferenceOptions::default(), &device)
        .unwrap_err()
        .to_string();
    assert!(e.contains("network's limit"), "{e}");
    // The ONNX export's size, before any graph is built.
    let e = InferenceOptions::default()
        .check_size([40000, 40000])
        .unwrap_err()
        .to_string();
    assert!(e.contains("40000x40000 is over the network's limit"), "{e}");
}
