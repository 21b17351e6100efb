//! PyTorch state dicts changed by hand, as a hostile or broken download would be: a record that
//! claims gigabytes, a deflated record that expands past its stated size (a zip bomb), a tensor
//! whose shape asks for more than its storage holds, a pickle that names code to run, files that
//! are no zip or whose directory lies. Each is refused by [`check_state_dict`] with one error
//! naming the file, before anything is allocated for what the file claims. The reference
//! network's own file, written by `torch.save`, and ours pass.

use std::io::{Cursor, Read, Write};
use std::path::{Path, PathBuf};

use stereo_io::pth::{Dtype, NamedArray, check_state_dict, encode_state_dict};

use crate::zip_edit;
use zip_edit::set_stated_size;

fn tensor(name: &str, shape: &[usize]) -> NamedArray {
    let n: usize = shape.iter().product();
    NamedArray {
        name: name.into(),
        shape: shape.to_vec(),
        data: (0..n).map(|i| i as f32 * 0.5).collect(),
    }
}

/// A small state dict of ours: shapes 7×11 and 3 (distinctive bytes in the pickle).
fn small() -> Vec<u8> {
    encode_state_dict(&[tensor("a.weight", &[7, 11]), tensor("a.bias", &[3])]).unwrap()
}

/// Every entry of an archive, in order.
fn entries(bytes: &[u8]) -> Vec<(String, Vec<u8>)> {
    let mut zip = zip::ZipArchive::new(Cursor::new(bytes)).unwrap();
    (0..zip.len())
        .map(|i| {
            let mut e = zip.by_index(i).unwrap();
            let mut data = Vec::new();
            e.read_to_end(&mut data).unwrap();
            (e.name().to_string(), data)
        })
        .collect()
}

/// An archive of `entries`, stored or deflated.
fn archive(entries: &[(String, Vec<u8>)], deflate: bool) -> Vec<u8> {
    let mut zip = zip::ZipWriter::new(Cursor::new(Vec::new()));
    let method = if deflate {
        zip::CompressionMethod::Deflated
    } else {
        zip::CompressionMethod::Stored
    };
    let options = zip::write::SimpleFileOptions::DEFAULT.compression_method(method);
    for (name, data) in entries {
        zip.start_file(name.as_str(), options).unwrap();
        zip.write_all(data).unwrap();
    }
    zip.finish().unwrap().into_inner()
}

fn with_entry(bytes: &[u8], name: &str, data: Vec<u8>, deflate: bool) -> Vec<u8> {
    let mut all = entries(bytes);
    all.iter_mut().find(|(n, _)| n == name).unwrap().1 = data;
    archive(&all, deflate)
}

fn replace(haystack: &[u8], from: &[u8], to: &[u8]) -> Vec<u8> {
    let at = haystack
        .windows(from.len())
        .position(|w| w == from)
        .expect("pattern in the pickle");
    [&haystack[..at], to, &haystack[at + from.len()..]].concat()
}

fn with_pickle(bytes: &[u8], from: &[u8], to: &[u8]) -> Vec<u8> {
    let pickle = entries(bytes)
        .into_iter()
        .find(|(n, _)| n.ends_with("data.pkl"))
        .unwrap()
        .1;
    with_entry(bytes, "archive/data.pkl", replace(&pickle, from, to), false)
}

/// The error of checking `bytes` as a file, checked to be one line naming the file.
fn refused(bytes: &[u8]) -> String {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("hostile.pth");
    std::fs::write(&path, bytes).unwrap();
    let e = check_state_dict(&path)
        .expect_err("a hostile state dict must be refused")
        .to_string();
    assert!(e.contains("hostile.pth") && !e.contains('\n'), "{e}");
    e
}

fn reference_weights() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/reference/crestereo/weights_seed0.pt")
}

#[test]
fn torch_save_files_and_ours_pass_with_their_tensors_listed() {
    let dir = tempfile::tempdir().unwrap();
    let ours = dir.path().join("ours.pth");
    std::fs::write(&ours, small()).unwrap();
    let listed = check_state_dict(&ours).unwrap();
    assert_eq!(listed.len(), 2);
    assert_eq!(
        (
            listed[0].name.as_str(),
            listed[0].dtype,
            listed[0].shape.as_slice()
        ),
        ("a.weight", Dtype::F32, &[7u64, 11][..])
    );
    // Deflated records (a re-zipped file) are read too.
    let deflated = dir.path().join("deflated.pth");
    std::fs::write(&deflated, archive(&entries(&small()), true)).unwrap();
    assert_eq!(check_state_dict(&deflated).unwrap(), listed);
    // The reference network, as torch.save wrote it: 94 tensors.
    let reference = check_state_dict(&reference_weights()).unwrap();
    assert_eq!(reference.len(), 94);
}

#[test]
fn a_record_claiming_3_gb_is_refused_before_it_is_read() {
    let mut bytes = small();
    set_stated_size(&mut bytes, "archive/data/0", 3_000_000_000);
    let e = refused(&bytes);
    assert!(
        e.contains("archive/data/0") && e.contains("over the limit of 1 GiB"),
        "{e}"
    );
}

#[test]
fn a_deflated_record_expanding_past_its_stated_size_is_cut_off() {
    // 64 MiB of zeros deflated (about 64 KB) where the shape asks for 308 bytes.
    let bytes = with_entry(&small(), "archive/data/0", vec![0; 64 << 20], true);
    let mut bytes = bytes;
    set_stated_size(&mut bytes, "archive/data/0", 308);
    let e = refused(&bytes);
    assert!(e.contains("expands to more than 308 bytes"), "{e}");
}

#[test]
fn a_tensor_whose_shape_disagrees_with_its_bytes_is_refused() {
    // The storage record cut to half.
    let e = refused(&with_entry(&small(), "archive/data/0", vec![0; 154], false));
    assert!(
        e.contains("needs 308 bytes") && e.contains("holds 154"),
        "{e}"
    );
    // The shape made 7×12 over a storage of 77 elements (BININT1 7, BININT1 11, TUPLE2).
    let e = refused(&with_pickle(&small(), b"K\x07K\x0b\x86", b"K\x07K\x0c\x86"));
    assert!(e.contains("reaches past its storage of 77 elements"), "{e}");
    // A shape asking for terabytes.
    let e = refused(&with_pickle(
        &small(),
        b"K\x07K\x0b\x86",
        b"J\xff\xff\xff\x7fJ\xff\xff\xff\x7f\x86",
    ));
    assert!(e.contains("over the readers' limit"), "{e}");
}

#[test]
fn a_pickle_naming_other_classes_or_opcodes_is_refused_before_anything_runs() {
    let e = refused(&with_pickle(
        &small(),
        b"ctorch._utils\n_rebuild_tensor_v2\n",
        b"cos\nsystem\n",
    ));
    assert!(e.contains("\"os.system\"") && e.contains("refused"), "{e}");
    // INST (`i`), an opcode that builds any class, where the dict begins.
    let e = refused(&with_pickle(&small(), b"\x80\x02", b"\x80\x02i"));
    assert!(e.contains("opcode 0x69"), "{e}");
}

#[test]
fn files_that_are_no_zip_or_whose_directory_lies_are_refused() {
    // A legacy (pre-1.6) torch.save file starts with a pickle and is no zip.
    let e = refused(&[&b"\x80\x02\x8a\x0al\xfc\x9cF\xf9 j\xa8P\x19."[..], &[0; 64]].concat());
    assert!(e.contains("no zip end-of-archive record"), "{e}");
    assert!(refused(b"PK").contains("too short"));
    // The end record claims 65534 entries in a directory of a few hundred bytes.
    let mut bytes = small();
    let end = bytes.len() - 22;
    bytes[end + 8..end + 12].copy_from_slice(&[0xfe, 0xff, 0xfe, 0xff]);
    let e = refused(&bytes);
    assert!(e.contains("claims 65534 entries"), "{e}");
}
