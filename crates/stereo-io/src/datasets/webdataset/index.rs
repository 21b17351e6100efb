//! Reading a split's index, `<split>.index.json`, trusting nothing in it: an index names the
//! files the reader opens, so each shard name must be a plain file name of the index's own
//! folder (no separator, no `..`, not absolute, no NUL or other control character), listed once.

use std::path::Path;

use super::{INDEX_FORMAT, INDEX_SUFFIX, INDEX_VERSION, ShardIndex};
use crate::error::{Error, Result, json_problem};
use crate::limits::{
    MAX_DOCUMENT_BYTES, check_length, open_inside, plain_file_name_problem, read_to_end_capped,
};

impl ShardIndex {
    /// Reads and checks the index of `split` in `root` ([`Self::parse`]): a regular file inside
    /// `root` ([`open_inside`]) of at most [`MAX_DOCUMENT_BYTES`].
    pub fn read(root: &Path, split: &str) -> Result<Self> {
        let name = format!("{split}{INDEX_SUFFIX}");
        let path = root.join(&name);
        let (file, len) = open_inside(root, &name)?;
        check_length(&path, "an index", len, MAX_DOCUMENT_BYTES)?;
        let bytes = read_to_end_capped(file, &path, MAX_DOCUMENT_BYTES, "the index")?;
        Self::parse(&bytes, &path)
    }

    /// Parses an index's bytes (`path` names them in errors, which never quote them) and checks
    /// its format, version and shard names.
    pub fn parse(bytes: &[u8], path: &Path) -> Result<Self> {
        let index: ShardIndex = serde_json::from_slice(bytes)
            .map_err(|e| Error::format(path, format!("unreadable index: {}", json_problem(&e))))?;
        if index.format != INDEX_FORMAT || index.version != INDEX_VERSION {
            let format = if index.format == INDEX_FORMAT {
                "this format"
            } else {
                "another format"
            };
            return Err(Error::format(
                path,
                format!(
                    "an index of {format}, version {}; this build reads {INDEX_FORMAT:?} version {INDEX_VERSION}",
                    index.version
                ),
            ));
        }
        let mut seen = std::collections::HashSet::new();
        for (n, shard) in index.shards.iter().enumerate() {
            if let Some(problem) = plain_file_name_problem(&shard.name) {
                return Err(Error::format(
                    path,
                    format!(
                        "shard {n}'s name {problem}: an index may only name files in its own folder"
                    ),
                ));
            }
            if !seen.insert(shard.name.as_str()) {
                return Err(Error::format(
                    path,
                    format!("shard {n} repeats the name of an earlier shard"),
                ));
            }
        }
        Ok(index)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn index(names: &[&str]) -> Vec<u8> {
        let shards: Vec<String> = names
            .iter()
            .map(|n| {
                format!(
                    r#"{{"name":{},"samples":1,"bytes":10}}"#,
                    serde_json::to_string(n).unwrap()
                )
            })
            .collect();
        format!(
            r#"{{"format":"{INDEX_FORMAT}","version":{INDEX_VERSION},"split":"train","samples":1,"shards":[{}]}}"#,
            shards.join(",")
        )
        .into_bytes()
    }

    #[test]
    fn shard_names_must_be_plain_names_in_the_folder() {
        let p = Path::new("train.index.json");
        assert!(ShardIndex::parse(&index(&["train-000000.tar"]), p).is_ok());
        for (bad, why) in [
            ("/etc/passwd", "separator"),
            ("../x", "separator"),
            ("..", "`..`"),
            ("", "empty"),
            ("a\0b", "control"),
        ] {
            let e = ShardIndex::parse(&index(&[bad]), p)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(why) && e.contains("train.index.json"),
                "{bad:?}: {e}"
            );
        }
        let e = ShardIndex::parse(&index(&["a.tar", "a.tar"]), p).unwrap_err();
        assert!(e.to_string().contains("repeats"), "{e}");
    }

    #[test]
    fn errors_never_quote_the_file() {
        let p = Path::new("train.index.json");
        let secret = "root:x:0:0:root:/root:/bin/bash";
        for bytes in [
            secret.as_bytes().to_vec(),
            format!(r#"{{"format":"{secret}","version":1,"split":"t","samples":0,"shards":[]}}"#)
                .into_bytes(),
            format!(r#"{{"format":1,"version":"{secret}"}}"#).into_bytes(),
        ] {
            let e = ShardIndex::parse(&bytes, p).unwrap_err().to_string();
            assert!(!e.contains("root"), "{e}");
        }
    }
}
