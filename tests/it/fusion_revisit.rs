//! The default fusion on a loop closure of the revisit set (docs/ablation.md, "Revisits"): an
//! evaluated pair no round of the fusion study saw, 28° and 1.4 m apart at 14 % overlap. Guards
//! its row: the default registers it as every branch alone does, and keeps the pose with the
//! largest share of keypoints consistent with the views (the union's, as committed). Skipped
//! without the real data, failing under CI=true.

use crate::common::{assert_largest_share, oracle_alike_params, refuse_with};
use cgenreg::dataset::Dataset;
use cgenreg::fusion::{FusionMode, Selection};
use cgenreg::pipeline::visibility::Candidate;
use cgenreg::pipeline::Registration;
use std::path::Path;

#[test]
fn default_fusion_registers_a_revisit_and_loses_to_no_branch() {
    let Some(_) = cgenreg::testing::test_data_root() else {
        return;
    };
    let manifest =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/manifests/redkitchen-revisit.toml");
    let pair = Dataset::load(&manifest)
        .unwrap()
        .load_pair("redkitchen-revisit/f160-f360")
        .unwrap();
    let p = oracle_alike_params(FusionMode::DEFAULT_WITH_IMAGE);
    let mut v = Registration::new(&p).keep(true).run(&pair).unwrap();
    let inputs = v.inputs.take().unwrap();
    let metrics = |r: &cgenreg::pipeline::RegistrationResult| r.metrics.unwrap();
    let alone = |mode, sel| refuse_with(&p, &pair, &inputs, mode, sel);
    let m = metrics(&v);
    assert!(m.success, "{m:?} {:?}", v.fusion_provenance());
    let geo = alone(FusionMode::GeometryOnly, Some(Selection::RowNn));
    let and = alone(FusionMode::NoisyAnd, None);
    for (name, r) in [
        ("geometry", &geo),
        ("image", &alone(FusionMode::ImageOnly, None)),
        ("Noisy-AND", &and),
    ] {
        // as committed: every branch registers this pair
        assert!(metrics(r).success, "{name}: {:?}", metrics(r));
    }
    // the pose kept is the union's (5.2° / 14 cm as committed; every candidate registers)
    let union = alone(FusionMode::Union, None);
    assert_eq!(v.target_from_source, union.target_from_source);
    let rep = v.visibility.as_ref().unwrap();
    assert_eq!((rep.source_views, rep.target_views), (50, 50));
    assert_eq!(rep.chosen, Candidate::Union, "{:?}", v.fusion_provenance());
    assert_largest_share(rep, Candidate::Union);
    assert!(v
        .fusion_provenance()
        .unwrap()
        .starts_with("fusion: visibility (kept the union pose"));
}
