//! The maps beside the disparity in a WebDataset sample: the members [`map_member`] names.

use std::borrow::Cow;
use std::path::Path;

use super::{MemberBytes, SampleEntry, WebDataset, facts_extra, member, sample_facts, streamed};
use crate::datasets::sample_maps::{check_size, size_in_extra};
use crate::datasets::{MapData, SampleMaps, map_member};
use crate::error::{Error, Result};
use crate::maps::MapKind;

impl WebDataset {
    /// The maps of a sample from its members' bytes (`get` as for [`Self::decode_with`]): the
    /// members [`map_member`] names, each of the size the sample's facts give (`<key>.json`).
    pub(super) fn maps_with<'a>(
        &self,
        s: &SampleEntry,
        get: &MemberBytes<'a>,
    ) -> Result<SampleMaps> {
        let mut out = SampleMaps::default();
        let present: Vec<(MapKind, &'static str, String)> = MapKind::ALL
            .into_iter()
            .flat_map(|k| crate::datasets::stereogen::VIEWS.map(|v| (k, v, map_member(k, v))))
            .filter(|(_, _, m)| s.members.iter().any(|x| &x.suffix == m))
            .collect();
        if present.is_empty() {
            return Ok(out);
        }
        let size = match get(member::JSON)? {
            Some(bytes) => size_in_extra(&facts_extra(&sample_facts(
                &bytes,
                &self.member_path(s, member::JSON),
            )?)),
            None => None,
        };
        for (kind, view, suffix) in present {
            let path = self.member_path(s, &suffix);
            let bytes =
                get(&suffix)?.ok_or_else(|| Error::format(&path, "missing from its sample"))?;
            let map = MapData::decode(kind, &bytes, &path)?;
            check_size(&path, &map, size)?;
            out.set(kind, view, map, &path)?;
        }
        Ok(out)
    }
}

/// The maps of one sample from its members as a streaming loader has them (see
/// [`decode_members`]): what [`WebDataset`]'s `maps` returns for it, bit for bit; none where
/// the sample has no map members.
pub fn decode_member_maps(
    shard: &Path,
    key: &str,
    members: &[(String, Vec<u8>)],
) -> Result<SampleMaps> {
    let (dataset, entry) = streamed(shard, key, members);
    dataset.maps_with(&entry, &|suffix| {
        Ok(members
            .iter()
            .find(|(s, _)| s == suffix)
            .map(|(_, b)| Cow::Borrowed(b.as_slice())))
    })
}
