//! 16-bit disparity PNG bytes (the image decoder behind every PNG and JPEG reader): decoded
//! within the limits, or one error line naming the file.
#![no_main]

use std::path::Path;

use stereogen_fuzz::{Limited, check};

#[global_allocator]
static ALLOC: Limited = Limited;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    check(
        stereo_io::decode_disparity_png16(bytes, Path::new("f.png"), 256.0),
        "f.png",
    );
});
