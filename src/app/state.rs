//! What the panels share besides the model: which tab is shown, how matches are coloured,
//! the selection (match, source point, hypothesis) and the command queue of this frame
//! ([`Shared`], handed to every tab and to the 3D view).

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use super::channel::Command;
use super::model::{HypothesisRow, InspectorModel};
use super::pair_order::PairSort;

/// The tabs of the central area.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Panel {
    Pairs,
    Views,
    View3d,
    Posterior,
    Plots,
    Stages,
    Compare,
    Hypotheses,
}

impl Panel {
    pub const ALL: [Panel; 8] = [
        Self::Pairs,
        Self::Views,
        Self::View3d,
        Self::Posterior,
        Self::Plots,
        Self::Stages,
        Self::Compare,
        Self::Hypotheses,
    ];
    pub fn label(self) -> &'static str {
        match self {
            Self::Pairs => "Pairs",
            Self::Views => "Views",
            Self::View3d => "3D",
            Self::Posterior => "Posterior",
            Self::Plots => "Plots",
            Self::Stages => "Stages",
            Self::Compare => "Compare",
            Self::Hypotheses => "Hypotheses",
        }
    }
    /// Parses a CLI name ("pairs", "views", "3d", "posterior", "plots", "stages", "compare",
    /// "hypotheses").
    pub fn from_name(s: &str) -> Option<Panel> {
        match s.to_ascii_lowercase().as_str() {
            "pairs" => Some(Self::Pairs),
            "views" => Some(Self::Views),
            "3d" | "view3d" => Some(Self::View3d),
            "posterior" => Some(Self::Posterior),
            "plots" => Some(Self::Plots),
            "stages" => Some(Self::Stages),
            "compare" => Some(Self::Compare),
            "hypotheses" => Some(Self::Hypotheses),
            _ => None,
        }
    }
}

/// How correspondences are coloured in the views and in 3D.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
pub enum MatchColorMode {
    /// One colour per match of the shown subset (as in the paper's figures).
    Categorical,
    /// Green inlier / red outlier under ground truth.
    #[value(name = "gt")]
    InlierOutlier,
    /// Turbo colormap of the fused confidence.
    Confidence,
}

impl MatchColorMode {
    pub const ALL: [MatchColorMode; 3] = [Self::Categorical, Self::InlierOutlier, Self::Confidence];
    pub fn label(self) -> &'static str {
        match self {
            Self::Categorical => "Categorical",
            Self::InlierOutlier => "Inlier / outlier (GT)",
            Self::Confidence => "Fused confidence",
        }
    }
}

/// How the Views tab draws a correspondence: line width (points; the end points grow with it)
/// and opacity (1 opaque). The hovered and selected matches are highlighted over it as before.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LineStyle {
    pub width: f32,
    pub alpha: f32,
}

impl LineStyle {
    pub const WIDTH: std::ops::RangeInclusive<f32> = 0.5..=6.0;
    pub const ALPHA: std::ops::RangeInclusive<f32> = 0.05..=1.0;
}

impl Default for LineStyle {
    fn default() -> Self {
        Self {
            width: 1.2,
            alpha: 1.0,
        }
    }
}

/// Selection and display state shared by the panels.
#[derive(Debug)]
pub struct UiState {
    pub tab: Panel,
    pub match_mode: MatchColorMode,
    /// Number of matches drawn (highest fused score first).
    pub match_count: usize,
    pub line_style: LineStyle,
    pub selected_match: Option<usize>,
    /// Set by whichever widget the pointer is over this frame.
    pub hovered_match: Option<usize>,
    prev_hovered: Option<usize>,
    pub selected_source_point: Option<usize>,
    pub pair_sort: PairSort,
    pub show_3d_below_views: bool,
    /// Draw only the matches the estimator kept (SC2-PCR inliers).
    pub only_survivors: bool,
    /// The hypothesis selected in the hypothesis browser: the 3D view shows the source under
    /// its pose and only its consensus is drawn.
    pub hypothesis: Option<HypothesisView>,
}

impl UiState {
    /// A new frame: the match hovered last frame stays highlighted until another widget
    /// reports one.
    pub fn begin_frame(&mut self) {
        self.prev_hovered = self.hovered_match.take();
    }
}

impl Default for UiState {
    fn default() -> Self {
        Self {
            tab: Panel::Views,
            // one set of view defaults for the window and `cgenreg screenshot`
            match_mode: MatchColorMode::InlierOutlier,
            match_count: 150,
            line_style: LineStyle::default(),
            selected_match: None,
            hovered_match: None,
            prev_hovered: None,
            selected_source_point: None,
            pair_sort: PairSort::WORST_RRE,
            show_3d_below_views: false,
            only_survivors: false,
            hypothesis: None,
        }
    }
}

/// What a panel function gets: the model (read-only), the shared UI state and the command
/// queue.
pub struct Shared<'a> {
    pub model: &'a InspectorModel,
    /// Changes whenever the model is replaced (GPU and texture caches key on it).
    pub model_gen: u64,
    /// Changes when the model's clouds do (another pair); a re-fusion keeps it, and with it
    /// the 3D camera and the uploaded points.
    pub scene_gen: u64,
    pub ui: &'a mut UiState,
    pub commands: &'a mut Vec<Command>,
}

impl Shared<'_> {
    /// Indices of the matches drawn, highest fused score first.
    pub fn shown_matches(&self) -> Vec<usize> {
        let mut idx: Vec<usize> = (0..self.model.matches.len())
            .filter(|&i| !self.ui.only_survivors || self.model.matches[i].survived == Some(true))
            .filter(|&i| {
                self.ui
                    .hypothesis
                    .as_ref()
                    .is_none_or(|h| h.inlier.get(i) == Some(&true))
            })
            .collect();
        idx.sort_by(|&a, &b| {
            self.model.matches[b]
                .score
                .total_cmp(&self.model.matches[a].score)
        });
        idx.truncate(self.ui.match_count);
        idx
    }
    /// The match to highlight: hovered now, hovered last frame, else selected.
    pub fn highlight(&self) -> Option<usize> {
        self.ui
            .hovered_match
            .or(self.ui.prev_hovered)
            .or(self.ui.selected_match)
    }
    pub fn select_match(&mut self, mi: usize) {
        self.ui.selected_match = Some(mi);
        if let Some(m) = self.model.matches.get(mi) {
            self.select_source_point(m.src);
        }
    }
    pub fn select_source_point(&mut self, i: usize) {
        if self.ui.selected_source_point != Some(i) {
            self.ui.selected_source_point = Some(i);
            if self.model.posterior_for(i).is_none() {
                self.commands.push(Command::InspectSourcePoint(i));
            }
        }
    }
}

/// A selected hypothesis as the 3D view and the match lists use it.
#[derive(Clone, Debug, PartialEq)]
pub struct HypothesisView {
    pub rank: usize,
    pub pose: Isometry3<f64>,
    /// Per match of the model: in the hypothesis's consensus.
    pub inlier: Vec<bool>,
}

impl HypothesisView {
    /// The 3D legend's row for the source drawn under this hypothesis.
    pub fn legend_label(&self) -> String {
        format!("source (hypothesis #{})", self.rank)
    }

    pub fn of(row: &HypothesisRow, n_matches: usize) -> Self {
        let mut inlier = vec![false; n_matches];
        for &i in &row.inliers {
            if let Some(x) = inlier.get_mut(i) {
                *x = true;
            }
        }
        HypothesisView {
            rank: row.rank,
            pose: row.pose,
            inlier,
        }
    }
}
