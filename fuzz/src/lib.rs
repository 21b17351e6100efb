//! What the fuzz targets share: an allocator that ends the process with a message (a crash that
//! libFuzzer records with its input) when one allocation asks for more than the readers' limit
//! of one buffer, or everything held at once passes three of them; and the properties every
//! error must have.

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Write;
use std::sync::atomic::{AtomicUsize, Ordering};

use stereo_io::limits::MAX_ALLOC;

/// The system allocator, counting.
pub struct Limited;

static LIVE: AtomicUsize = AtomicUsize::new(0);
const ONE: usize = MAX_ALLOC as usize;
const ALL: usize = 3 * MAX_ALLOC as usize;

fn over(message: &[u8]) -> ! {
    // Nothing here allocates: this runs inside the allocator.
    let _ = std::io::stderr().write_all(message);
    std::process::abort()
}

fn count(size: usize) {
    if size > ONE {
        over(b"fuzz: one allocation over the readers' limit (stereo_io::limits::MAX_ALLOC)\n");
    }
    if LIVE.fetch_add(size, Ordering::Relaxed) + size > ALL {
        over(b"fuzz: memory held over three times the readers' limit of one buffer\n");
    }
}

// SAFETY: every call goes to the system allocator with the same arguments; the counting only
// reads sizes.
unsafe impl GlobalAlloc for Limited {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count(layout.size());
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count(layout.size());
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > layout.size() {
            count(new_size - layout.size());
            if new_size > ONE {
                over(b"fuzz: one allocation over the readers' limit (stereo_io::limits::MAX_ALLOC)\n");
            }
        } else {
            LIVE.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// An error as the user sees it: one line that names `name` (the file it is about).
pub fn check_error(e: &stereo_io::Error, name: &str) {
    let text = e.to_string();
    assert!(
        !text.contains('\n'),
        "an error of more than one line: {text}"
    );
    assert!(
        text.contains(name),
        "an error that does not name {name}: {text}"
    );
}

/// [`check_error`] on the error of `r`, if it is one.
pub fn check<T>(r: stereo_io::Result<T>, name: &str) -> Option<T> {
    match r {
        Ok(v) => Some(v),
        Err(e) => {
            check_error(&e, name);
            None
        }
    }
}
