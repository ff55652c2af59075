//! The `visibility` fusion's share score (docs/ablation.md, "The fusion study, sixth round") on
//! the pattern it was chosen for: only the image branch alone registers, the other three poses
//! are far off, and the default keeps the image pose because a far larger share of its seen
//! keypoints agrees with the depth views. Once on a development pair, once on the evaluated pair
//! redkitchen-rgbd 3DLoMatch 0-8 (the pair earlier rules lost). Oracle RGB + ALIKE-t. Skipped
//! without the real data, failing under CI=true.

use crate::common::{oracle_alike_params, refuse_with};
use cgenreg::dataset::Dataset;
use cgenreg::fusion::{FusionMode, Selection};
use cgenreg::pipeline::visibility::Candidate;
use cgenreg::pipeline::Registration;
use std::path::Path;

/// Registers `id` of `manifest` with the default fusion and checks that it keeps the image
/// pose, registers as image alone does, and that geometry alone and Noisy-AND do not.
fn keeps_the_image_pose_only_the_image_branch_registers(manifest: &str, id: &str) {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join(manifest);
    let pair = Dataset::load(&manifest).unwrap().load_pair(id).unwrap();
    let p = oracle_alike_params(FusionMode::DEFAULT_WITH_IMAGE);
    let mut v = Registration::new(&p).keep(true).run(&pair).unwrap();
    let inputs = v.inputs.take().unwrap();
    let ok = |r: &cgenreg::pipeline::RegistrationResult| r.metrics.unwrap().success;
    let alone = |mode, sel| refuse_with(&p, &pair, &inputs, mode, sel);
    let image = alone(FusionMode::ImageOnly, None);
    let geo = alone(FusionMode::GeometryOnly, Some(Selection::RowNn));
    let and = alone(FusionMode::NoisyAnd, None);
    // as committed: only the image branch registers this pair
    assert!(
        ok(&image) && !ok(&geo) && !ok(&and),
        "{id}: {:?} {:?} {:?}",
        image.metrics,
        geo.metrics,
        and.metrics
    );
    let line = v.fusion_provenance().unwrap();
    assert!(ok(&v), "{id}: {:?} {line}", v.metrics);
    assert_eq!(v.target_from_source, image.target_from_source, "{line}");
    let rep = v.visibility.as_ref().unwrap();
    assert_eq!(rep.chosen, Candidate::Image, "{line}");
    assert!(
        line.starts_with("fusion: visibility (kept the image pose"),
        "{line}"
    );
    // the share decides, not the count: every other pose's F is below the image pose's
    let image_f = rep.candidates[3].share;
    for c in &rep.candidates[..3] {
        assert!(c.share < image_f, "{id}: {:?}", rep.candidates);
    }
}

/// D6 f147-f347 (fragments at 50k+47, 3DLoMatch-like): image alone at 4.8° / 13 cm, the other
/// poses 80-112° off; F 0.815 against 0.41-0.44.
#[test]
fn keeps_the_image_pose_on_a_development_pair_only_the_image_branch_registers() {
    let Some(_) = cgenreg::testing::test_data_root() else {
        return;
    };
    keeps_the_image_pose_only_the_image_branch_registers(
        "assets/manifests/redkitchen-dev6.toml",
        "redkitchen-dev6/f147-f347",
    );
}

/// redkitchen-rgbd 3DLoMatch 0-8 (evaluated): the image branch alone registers (1.8° / 22 cm);
/// the union and Noisy-AND have the right rotation but are 1.1 m off.
#[test]
fn keeps_the_image_pose_on_the_evaluated_pair_earlier_rules_lost() {
    let Some(_) = cgenreg::testing::test_data_root() else {
        return;
    };
    keeps_the_image_pose_only_the_image_branch_registers(
        "assets/manifests/redkitchen-rgbd.toml",
        "redkitchen-rgbd/0-8",
    );
}
