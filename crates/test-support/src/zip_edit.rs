//! Editing a zip archive's bytes the way a hostile copy would, for the weights tests of
//! stereo-io and crestereo.

/// Sets the uncompressed size of entry `name` in its local and central headers.
pub fn set_stated_size(bytes: &mut [u8], name: &str, size: u32) {
    let mut found = 0;
    for at in 0..bytes.len().saturating_sub(46) {
        let (field, name_len_at) = match &bytes[at..at + 4] {
            [0x50, 0x4b, 0x03, 0x04] => (at + 22, at + 26),
            [0x50, 0x4b, 0x01, 0x02] => (at + 24, at + 28),
            _ => continue,
        };
        let len = u16::from_le_bytes([bytes[name_len_at], bytes[name_len_at + 1]]) as usize;
        let name_at = if bytes[at + 2] == 3 { at + 30 } else { at + 46 };
        if bytes.get(name_at..name_at + len) == Some(name.as_bytes()) {
            bytes[field..field + 4].copy_from_slice(&size.to_le_bytes());
            found += 1;
        }
    }
    assert_eq!(found, 2, "local and central header of {name}");
}
