//! What a data set's manifest sets for its runs (its protocol, scene description and geometric
//! features), and the one resolution of a run's protocol that every entry point uses:
//! `register` (and so the Python package), `bench`, `screenshot`, and the inspector's
//! `inspect --manifest`, *Open…*, a relaunch and a pair selected in the browser.

use crate::dataset::manifest::Dataset;
use crate::features::DescriptorName;
use crate::pipeline::params::{Preset, RegisterParams};

/// What a data set's manifest sets for its runs unless an option does: its protocol
/// (`preset`, a pair's own before the data set's), its scene description (`scene_prompt`) and
/// its geometric features (`geo_features`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ManifestSettings {
    pub preset: Option<Preset>,
    pub scene_prompt: Option<String>,
    pub geo_features: Option<DescriptorName>,
}

impl ManifestSettings {
    /// The data set's settings.
    pub fn of(ds: &Dataset) -> Self {
        ManifestSettings {
            preset: ds.preset,
            scene_prompt: ds.scene_prompt.clone(),
            geo_features: ds.geo_features,
        }
    }

    /// The settings of pair `id` (its own preset, else the data set's).
    pub fn of_pair(ds: &Dataset, id: &str) -> Self {
        ManifestSettings {
            preset: ds.preset_of(id),
            ..Self::of(ds)
        }
    }

    /// The protocol a run of these data uses: `chosen` (an option naming one), else the
    /// manifest's, else indoor.
    pub fn preset(&self, chosen: Option<Preset>) -> Preset {
        resolve_preset(chosen, self.preset)
    }
}

/// The protocol of a run: the one `chosen` (`--preset`), else the one the manifest names for the
/// pair (its own, else the data set's), else indoor. Every entry point resolves it here.
pub fn resolve_preset(chosen: Option<Preset>, manifest: Option<Preset>) -> Preset {
    chosen.or(manifest).unwrap_or_default()
}

/// `params` taken to the data `data` (a name for people) whose manifest settings are `m`: the
/// protocol the manifest names (indoor when it names none, as `register` runs it) is applied
/// when `params` is not already under it. The inspector opens data, reopens it at a relaunch and
/// selects a pair of its own preset through this, so a protocol chosen by hand on other data is
/// never carried over silently: the notice returned says what changed (None: nothing did).
pub fn adopt_preset(
    params: &mut RegisterParams,
    data: &str,
    m: &ManifestSettings,
) -> Option<String> {
    let want = m.preset(None);
    let now = Preset::of(params);
    if now == Some(want) {
        return None;
    }
    let before = match now {
        Some(p) => format!("the {} preset", p.name()),
        None => format!("your own scale settings (voxel {} m)", params.voxel),
    };
    want.apply(params);
    let why = match m.preset {
        Some(_) => format!("{data} names the {} preset", want.label()),
        None => format!(
            "{data} names no preset: the {} protocol, as `register` runs it",
            want.name()
        ),
    };
    Some(format!(
        "{why}: voxel {} m, every distance following it, success {} (replaces {before}; \
         Settings, \u{201c}Scale & success\u{201d})",
        want.voxel(),
        params.success.primary.label()
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_option_wins_then_the_manifest_then_indoor() {
        let m = ManifestSettings {
            preset: Some(Preset::Outdoor),
            ..Default::default()
        };
        assert_eq!(m.preset(None), Preset::Outdoor);
        assert_eq!(m.preset(Some(Preset::Indoor)), Preset::Indoor);
        assert_eq!(ManifestSettings::default().preset(None), Preset::Indoor);
    }

    #[test]
    fn a_preset_of_other_data_is_replaced_with_a_notice() {
        let outdoor = ManifestSettings {
            preset: Some(Preset::Outdoor),
            ..Default::default()
        };
        // indoor params opened on outdoor data
        let mut p = RegisterParams::default();
        let n = adopt_preset(&mut p, "kitti07", &outdoor).unwrap();
        assert_eq!(p, RegisterParams::preset(Preset::Outdoor));
        assert!(
            n.contains("kitti07 names the outdoor") && n.contains("0.3 m"),
            "{n}"
        );
        // already under it: nothing changes, no notice
        assert_eq!(adopt_preset(&mut p, "kitti07", &outdoor), None);
        // outdoor carried to data naming none: back to indoor, saying so
        let n = adopt_preset(&mut p, "redkitchen", &ManifestSettings::default()).unwrap();
        assert_eq!(p, RegisterParams::default());
        assert!(
            n.contains("names no preset") && n.contains("replaces the outdoor"),
            "{n}"
        );
        // a voxel set by hand is named in the notice
        p.voxel = 0.1;
        let n = adopt_preset(&mut p, "kitti07", &outdoor).unwrap();
        assert!(n.contains("voxel 0.1 m"), "{n}");
    }
}
