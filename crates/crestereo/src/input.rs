//! The network's input image type and the one conversion into it.
//!
//! Every image reaches the network the same way, for `infer`, `eval` and training alike: a file
//! is decoded by `stereo-io` to 8-bit RGB ([`stereo_io::read_rgb`], or a dataset reader, which
//! uses it), then [`BgrImage::from_rgb`] makes the planar BGR floats the network takes.
//!
//! The rule for other inputs follows from that decode, and matches the reference's
//! `cv2.imread(path, IMREAD_COLOR)`: grey images are repeated into three channels, alpha is
//! dropped, and **16-bit images are reduced to 8 bits** (the `image` crate rounds, `v / 257`;
//! OpenCV truncates, `v >> 8`, so on 16-bit files the two may differ by one grey level). 8-bit
//! files give exactly OpenCV's values.

use burn::prelude::*;

/// A planar float image (3, H, W) in BGR order, values 0..255 — the network's input format.
#[derive(Debug, Clone, PartialEq)]
pub struct BgrImage {
    pub width: usize,
    pub height: usize,
    /// `3 · height · width` values: the whole B plane, then G, then R.
    pub data: Vec<f32>,
}

impl BgrImage {
    pub fn zeros(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            data: vec![0.0; 3 * width * height],
        }
    }

    /// Interleaved 8-bit RGB (as `stereo-io` decodes images) to planar BGR.
    pub fn from_rgb(img: &stereo_io::RgbImage) -> Self {
        let n = img.width * img.height;
        assert_eq!(
            img.data.len(),
            3 * n,
            "RGB buffer does not match {}x{}",
            img.width,
            img.height
        );
        let mut out = Self::zeros(img.width, img.height);
        for (i, rgb) in img.data.chunks_exact(3).enumerate() {
            out.data[i] = f32::from(rgb[2]);
            out.data[n + i] = f32::from(rgb[1]);
            out.data[2 * n + i] = f32::from(rgb[0]);
        }
        out
    }

    /// Channel `c` (0 = B, 1 = G, 2 = R).
    pub fn plane(&self, c: usize) -> &[f32] {
        let n = self.width * self.height;
        &self.data[c * n..(c + 1) * n]
    }

    pub fn plane_mut(&mut self, c: usize) -> &mut [f32] {
        let n = self.width * self.height;
        &mut self.data[c * n..(c + 1) * n]
    }

    /// The image as a (1, 3, H, W) tensor.
    pub fn to_tensor<B: Backend>(&self, device: &B::Device) -> Tensor<B, 4> {
        Tensor::from_data(
            TensorData::new(self.data.clone(), [1, 3, self.height, self.width]),
            device,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rgb_becomes_planar_bgr() {
        let rgb = stereo_io::RgbImage {
            width: 2,
            height: 1,
            data: vec![1, 2, 3, 4, 5, 6],
        };
        let bgr = BgrImage::from_rgb(&rgb);
        assert_eq!(bgr.data, vec![3.0, 6.0, 2.0, 5.0, 1.0, 4.0]);
        assert_eq!(bgr.plane(2), &[1.0, 4.0]);
    }

    /// 16-bit files take the same 8-bit path as everything else.
    #[test]
    fn sixteen_bit_png_reads_as_its_8_bit_values() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("deep.png");
        let samples: Vec<u16> = vec![
            0,
            0,
            0,
            65535,
            65535,
            65535,
            257 * 100,
            257 * 200 + 100,
            257 * 7,
        ];
        let img = stereo_io::Image {
            width: 3,
            height: 1,
            channels: 3,
            samples: stereo_io::Samples::U16(samples),
        };
        stereo_io::write_png(&path, &img).unwrap();
        let bgr = BgrImage::from_rgb(&stereo_io::read_rgb(&path).unwrap());
        assert_eq!(
            bgr.data,
            vec![0.0, 255.0, 7.0, 0.0, 255.0, 200.0, 0.0, 255.0, 100.0]
        );
    }
}
