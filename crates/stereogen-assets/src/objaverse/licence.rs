//! Objaverse licences. Objects carry Sketchfab's licence slug in their annotation (`by`, `by-sa`,
//! `by-nd`, `by-nc`, `by-nc-sa`, `by-nc-nd`, `cc0`); users may also write them `cc-by`, `CC-BY-4.0`.

use anyhow::bail;

/// The slug a user's licence name stands for: lower case, without a `cc-` prefix or a version.
pub fn normalise(name: &str) -> String {
    let mut s = name.trim().to_ascii_lowercase().replace(['_', ' '], "-");
    if let Some(rest) = s.strip_prefix("cc-") {
        s = rest.to_string();
    }
    // "by-4.0" -> "by"
    if let Some((head, tail)) = s.rsplit_once('-')
        && tail.chars().all(|c| c.is_ascii_digit() || c == '.')
        && !tail.is_empty()
    {
        s = head.to_string();
    }
    if s == "cc0-1.0" || s == "zero" {
        "cc0".into()
    } else {
        s
    }
}

/// Whether a licence forbids commercial use or derivatives (renders are derivatives).
pub fn is_restricted(slug: &str) -> bool {
    slug.split('-').any(|part| part == "nc" || part == "nd")
}

/// The licences a fetch accepts: the user's list, normalised; NC/ND only with `allow_restricted`.
pub fn accepted(names: &[String], allow_restricted: bool) -> anyhow::Result<Vec<String>> {
    let mut out = Vec::new();
    for name in names {
        let slug = normalise(name);
        if slug.is_empty() {
            continue;
        }
        if is_restricted(&slug) && !allow_restricted {
            bail!(
                "--license {name}: {slug} forbids commercial use or derivative works (rendered images are derivatives); pass --allow-nc-nd to fetch such objects anyway"
            );
        }
        if !out.contains(&slug) {
            out.push(slug);
        }
    }
    if out.is_empty() {
        bail!("--license names no licence");
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_normalise_to_sketchfab_slugs_and_restricted_ones_need_consent() {
        assert_eq!(normalise("CC-BY"), "by");
        assert_eq!(normalise("cc-by-4.0"), "by");
        assert_eq!(normalise("CC0"), "cc0");
        assert_eq!(normalise("CC0-1.0"), "cc0");
        assert_eq!(normalise("by-nc-sa"), "by-nc-sa");
        assert!(is_restricted("by-nc") && is_restricted("by-nd") && !is_restricted("by-sa"));
        assert_eq!(
            accepted(&["cc0".into(), "cc-by".into()], false).unwrap(),
            ["cc0", "by"]
        );
        let err = accepted(&["by-nc".into()], false).unwrap_err().to_string();
        assert!(err.contains("--allow-nc-nd"), "{err}");
        assert_eq!(accepted(&["by-nc".into()], true).unwrap(), ["by-nc"]);
    }
}
