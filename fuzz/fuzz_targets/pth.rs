//! PyTorch state dict bytes through the check every `.pt`/`.pth` passes before it is loaded:
//! accepted within the limits, or one error line naming the file.
#![no_main]

use std::io::Cursor;
use std::path::Path;

use stereogen_fuzz::{Limited, check};

#[global_allocator]
static ALLOC: Limited = Limited;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    let path = Path::new("f.pth");
    let r = stereo_io::pth::check_state_dict_from(Cursor::new(bytes), bytes.len() as u64, path);
    check(r, "f.pth");
});
