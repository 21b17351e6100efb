//! `--devices`: the devices of this process, one model replica each, in the spelling PyTorch
//! users know (`cuda:0,cuda:1`), or a count as in Lightning (`--devices 4` = indices 0..4 of
//! `--device`).

use anyhow::{Result, bail};

use super::DeviceKind;

/// One entry of `--devices`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceIndex {
    Index(usize),
    /// `vulkan:cpu`: the CPU Vulkan adapter (Mesa's lavapipe).
    CpuAdapter,
}

/// The parsed list: one backend kind, one or more devices.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceList {
    pub kind: DeviceKind,
    pub devices: Vec<DeviceIndex>,
}

/// Parses `--devices` (`default` is `--device`'s kind, used for a bare count).
pub fn parse_devices(spec: &str, default: DeviceKind) -> Result<DeviceList> {
    let spec = spec.trim();
    if let Ok(n) = spec.parse::<usize>() {
        if n == 0 {
            bail!("--devices 0: at least one device");
        }
        return Ok(DeviceList {
            kind: default,
            devices: (0..n).map(DeviceIndex::Index).collect(),
        });
    }
    let mut kind = None;
    let mut devices = Vec::new();
    for entry in spec.split(',').map(str::trim) {
        let (name, index) = entry.split_once(':').unwrap_or((entry, "0"));
        let k = match name {
            "cpu" => DeviceKind::Cpu,
            "cuda" => DeviceKind::Cuda,
            "vulkan" | "wgpu" => DeviceKind::Vulkan,
            other => bail!(
                "--devices {spec}: unknown device `{other}` (cpu, cuda or vulkan, e.g. cuda:0,cuda:1)"
            ),
        };
        if kind.is_some_and(|seen| seen != k) {
            bail!("--devices {spec}: one kind of device per process (one backend)");
        }
        kind = Some(k);
        let device = match (k, index) {
            (DeviceKind::Vulkan, "cpu") => DeviceIndex::CpuAdapter,
            (_, i) => DeviceIndex::Index(i.parse().map_err(|_| {
                anyhow::anyhow!("--devices {spec}: `{entry}` needs a device number, e.g. {name}:0")
            })?),
        };
        if k != DeviceKind::Cpu && devices.contains(&device) {
            bail!("--devices {spec}: `{entry}` is named twice");
        }
        devices.push(device);
    }
    Ok(DeviceList {
        kind: kind.unwrap_or(default),
        devices,
    })
}

/// A backend's device made from an entry of `--devices`.
pub trait FromDeviceIndex: Sized {
    fn from_index(index: DeviceIndex) -> Result<Self>;
}

impl FromDeviceIndex for burn::backend::flex::FlexDevice {
    /// Every CPU replica runs on the same cores (Flex has one device): for tests and for
    /// comparing with a multi-process run on one machine.
    fn from_index(_: DeviceIndex) -> Result<Self> {
        Ok(Self)
    }
}

#[cfg(feature = "cuda")]
impl FromDeviceIndex for burn::backend::cuda::CudaDevice {
    fn from_index(index: DeviceIndex) -> Result<Self> {
        match index {
            DeviceIndex::Index(i) => Ok(Self::new(i)),
            DeviceIndex::CpuAdapter => bail!("cuda:cpu is not a CUDA device"),
        }
    }
}

#[cfg(feature = "wgpu")]
impl FromDeviceIndex for burn::backend::wgpu::WgpuDevice {
    /// `vulkan:N`: the N-th discrete GPU; `vulkan:cpu`: the CPU adapter (lavapipe).
    fn from_index(index: DeviceIndex) -> Result<Self> {
        Ok(match index {
            DeviceIndex::Index(i) => Self::DiscreteGpu(i),
            DeviceIndex::CpuAdapter => Self::Cpu,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spellings() {
        let l = parse_devices("cuda:0,cuda:1", DeviceKind::Cpu).unwrap();
        assert_eq!(l.kind, DeviceKind::Cuda);
        assert_eq!(
            l.devices,
            vec![DeviceIndex::Index(0), DeviceIndex::Index(1)]
        );
        let l = parse_devices("3", DeviceKind::Vulkan).unwrap();
        assert_eq!((l.kind, l.devices.len()), (DeviceKind::Vulkan, 3));
        let l = parse_devices("cpu,cpu", DeviceKind::Cuda).unwrap();
        assert_eq!((l.kind, l.devices.len()), (DeviceKind::Cpu, 2));
        assert_eq!(
            parse_devices("vulkan:cpu", DeviceKind::Cpu)
                .unwrap()
                .devices,
            vec![DeviceIndex::CpuAdapter]
        );
        for (bad, says) in [
            ("cuda:0,vulkan:0", "one kind"),
            ("tpu:0", "unknown device"),
            ("cuda:x", "needs a device number"),
            ("cuda:1,cuda:1", "named twice"),
            ("0", "at least one"),
        ] {
            let e = parse_devices(bad, DeviceKind::Cpu).unwrap_err().to_string();
            assert!(e.contains(says), "{bad}: {e}");
        }
    }
}
