//! The “Scale & success” section: the preset, the keypoint voxel, the scale hypotheses, every
//! distance that follows the voxel and the success criteria.

use super::*;

/// The preset (indoor / outdoor / outdoor-search), the keypoint voxel, the scale hypotheses, every distance that follows it (with
/// its value at the voxel, or set by hand) and the success criterion: all fields of
/// `params` itself ([`Preset::apply`], [`Scaled`]).
pub(super) fn scale_controls(ui: &mut egui::Ui, params: &mut RegisterParams) {
    let current = Preset::of(params);
    let l = ui.label("Preset");
    egui::ComboBox::from_id_salt("Preset")
        .selected_text(current.map_or("custom", Preset::label))
        .width(combo_width(ui))
        .show_ui(ui, |ui| {
            for p in Preset::ALL {
                if ui.selectable_label(current == Some(p), p.label()).clicked() {
                    p.apply(params);
                }
            }
        })
        .response
        .labelled_by(l.id);
    ui.horizontal(|ui| {
        let l = ui.label("Keypoint voxel (m)");
        ui.add(
            egui::DragValue::new(&mut params.voxel)
                .update_while_editing(false)
                .speed(0.005)
                .range(0.001..=10.0),
        )
        .labelled_by(l.id)
        .on_hover_text("FPFH radii follow it (2 v, 5 v), and so does every distance ticked below");
    });
    ui.horizontal(|ui| {
        let l = ui.label("Scale hypotheses");
        ui.add(
            egui::DragValue::new(&mut params.scales)
                .update_while_editing(false)
                .range(1..=6),
        )
        .labelled_by(l.id)
        .on_hover_text(
            "1: the voxel alone; N: the voxels v, 2 v, ..., 2^(N-1) v, the pose most \
                 consistent with both scans' range views kept",
        );
    });
    let v = params.voxel;
    if let EstimatorKind::Sc2Pcr(s) = &mut params.estimator {
        scaled_field(ui, "SC2-PCR d_thre", &mut s.d_thre, v, THRESHOLD_PER_VOXEL);
        scaled_field(
            ui,
            "SC2-PCR inlier threshold",
            &mut s.inlier_threshold,
            v,
            THRESHOLD_PER_VOXEL,
        );
    }
    if let EstimatorKind::Ransac(r) = &mut params.estimator {
        scaled_field(
            ui,
            "RANSAC inlier distance",
            &mut r.distance_threshold,
            v,
            RANSAC_PER_VOXEL,
        );
    }
    scaled_field(
        ui,
        "GT inlier-ratio threshold",
        &mut params.inlier_threshold,
        v,
        THRESHOLD_PER_VOXEL,
    );
    if let Some(ib) = &mut params.image {
        scaled_field(
            ui,
            "Lift radius",
            &mut ib.lift_radius,
            v,
            LIFT_RADIUS_PER_VOXEL,
        );
    }
    let c = &mut params.success.primary;
    ui.horizontal(|ui| {
        ui.label("Success: RRE ≤");
        ui.add(
            egui::DragValue::new(&mut c.max_rre_deg)
                .update_while_editing(false)
                .speed(0.5)
                .range(0.0..=180.0)
                .suffix("°"),
        );
        ui.label("RTE ≤");
        ui.add(
            egui::DragValue::new(&mut c.max_rte_m)
                .update_while_editing(false)
                .speed(0.01)
                .range(0.0..=100.0)
                .suffix(" m"),
        );
    });
    if let Some(a) = params.success.also {
        ui.label(format!("also reported: {}", a.label()));
    }
}

/// One distance: "follows voxel" ticked shows its value at the voxel; unticked, the value is
/// the user's (starting from the one it had).
fn scaled_field<T: Metres + egui::emath::Numeric>(
    ui: &mut egui::Ui,
    label: &str,
    value: &mut Scaled<T>,
    voxel: f64,
    per_voxel: f64,
) {
    ui.horizontal(|ui| {
        let mut follows = value.follows_voxel();
        let now = value.at(voxel, per_voxel);
        if ui
            .checkbox(&mut follows, format!("{label} = {per_voxel} v"))
            .on_hover_text("ticked: follows the keypoint voxel; unticked: the value set here")
            .changed()
        {
            *value = if follows {
                Scaled::FollowVoxel
            } else {
                Scaled::Set(now)
            };
        }
        match value {
            Scaled::Set(x) => {
                ui.add(
                    egui::DragValue::new(x)
                        .update_while_editing(false)
                        .speed(0.005)
                        .range(0.001..=100.0)
                        .suffix(" m"),
                );
            }
            Scaled::FollowVoxel => {
                ui.label(format!("{:.3} m", now.to_m()));
            }
        }
    });
}
