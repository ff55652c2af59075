//! Opening files from the UI: the native dialog first (off the UI thread), the in-app browser
//! when there is none, drag and drop, and the two runs of the Compare tab.

use super::*;

/// A native dialog that answers "cancelled" sooner than this never opened.
pub(super) const NO_DIALOG_WITHIN: std::time::Duration = std::time::Duration::from_millis(400);

impl App {
    /// Compares two bench runs in the Compare tab (read off the UI thread).
    pub fn compare_runs(&mut self, a: PathBuf, b: PathBuf) {
        self.tabs.compare.request(a, b);
        self.ui_state.tab = Panel::Compare;
    }

    /// What a file dialog or the in-app browser chose: data for the worker, or two runs to
    /// compare.
    pub(super) fn open_paths(&mut self, kind: OpenKind, paths: Vec<PathBuf>) {
        if kind != OpenKind::Comparison {
            return self.send(Command::Open { kind, paths });
        }
        match <[PathBuf; 2]>::try_from(paths) {
            Ok([a, b]) => self.compare_runs(a, b),
            Err(p) => self.push_log(
                LogLevel::Error,
                format!(
                    "compare runs: choose two bench JSONs (run A, then run B), got {}",
                    p.len()
                ),
            ),
        }
    }

    /// Carries out what the Compare tab asked for.
    pub(super) fn compare_action(
        &mut self,
        action: tabs::compare::CompareAction,
        commands: &mut Vec<Command>,
        open_request: &mut Option<OpenKind>,
    ) {
        use tabs::compare::CompareAction;
        match action {
            CompareAction::Browse => *open_request = Some(OpenKind::Comparison),
            CompareAction::TakeSettings(side) => {
                self.tabs.compare.settings.take(side, self.params.clone());
            }
            CompareAction::Send(c) => commands.push(c),
            CompareAction::OpenManifest(m) => commands.push(Command::Open {
                kind: OpenKind::Manifest,
                paths: vec![m],
            }),
            CompareAction::Open(side, pair) => {
                let Some(l) = &self.tabs.compare.loaded else {
                    return;
                };
                let run = l.run(side);
                match &run.params {
                    Ok(p) => {
                        let text = format!(
                            "{pair}: opening with run {}'s settings ({})",
                            side.label(),
                            run.name
                        );
                        self.params = p.clone();
                        commands.push(Command::OpenPairWith {
                            pair,
                            params: p.clone(),
                        });
                        self.push_log(LogLevel::Info, text);
                        self.ui_state.tab = Panel::Views;
                    }
                    Err(e) => self.push_log(LogLevel::Error, e.clone()),
                }
            }
        }
    }

    /// The in-app browser, starting where the last opened data lies.
    pub fn open_browser(&mut self, kind: OpenKind) {
        let start = self
            .last_opened
            .as_ref()
            .and_then(|(_, p)| p.first().cloned());
        self.browser = Some(file_browser::FileBrowser::new(kind, start.as_deref()));
    }

    /// Native dialog on a thread (the UI keeps running while it is open); the in-app
    /// browser where native dialogs are refused or unavailable.
    pub(super) fn open_dialog(&mut self, kind: OpenKind, ctx: &egui::Context) {
        if self.dialog.is_some() {
            return;
        }
        if !self.allow_dialogs || self.builtin_browser {
            self.open_browser(kind);
            return;
        }
        let (tx, rx) = channel();
        self.dialog = Some((rx, std::time::Instant::now()));
        let ctx = ctx.clone();
        let spawned = std::thread::Builder::new()
            .name("cgenreg-dialog".into())
            .spawn(move || {
                let fut = async move {
                    let d = rfd::AsyncFileDialog::new();
                    if kind.wants_folder() {
                        d.pick_folder().await.map(|h| vec![h.path().to_path_buf()])
                    } else if kind == OpenKind::Comparison {
                        d.add_filter("bench JSON (run A, then run B)", &["json"])
                            .pick_files()
                            .await
                            .map(|v| v.iter().map(|h| h.path().to_path_buf()).collect())
                    } else if kind == OpenKind::TwoClouds {
                        // a third file may be the 4x4 ground truth (.txt / gt.npy)
                        d.add_filter(
                            "point clouds (+ GT .txt)",
                            &["ply", "pcd", "xyz", "npy", "bin", "pth", "txt"],
                        )
                        .pick_files()
                        .await
                        .map(|v| v.iter().map(|h| h.path().to_path_buf()).collect())
                    } else {
                        d.add_filter("manifest", &["json", "toml", "txt"])
                            .pick_file()
                            .await
                            .map(|h| vec![h.path().to_path_buf()])
                    }
                };
                let r = block_on(fut);
                let _ = tx.send((kind, r));
                ctx.request_repaint();
            });
        if spawned.is_err() {
            self.dialog = None;
            self.push_log(LogLevel::Error, "could not start the file dialog thread");
        }
    }

    pub(super) fn handle_drops(&mut self, ctx: &egui::Context) {
        let dropped: Vec<PathBuf> = ctx.input(|i| {
            i.raw
                .dropped_files
                .iter()
                .map(|f| f.path().to_path_buf())
                .filter(|p| !p.as_os_str().is_empty())
                .collect()
        });
        if !dropped.is_empty() {
            let kind = classify_drop(&dropped);
            self.send(Command::Open {
                kind,
                paths: dropped,
            });
        }
    }

    /// What the in-app file browser answered, if it did this frame.
    pub(super) fn browser_outcome(&mut self, ctx: &egui::Context, commands: &mut Vec<Command>) {
        let Some(b) = &mut self.browser else {
            return;
        };
        match b.show(ctx) {
            Some(file_browser::BrowserOutcome::Open(OpenKind::Comparison, paths)) => {
                self.browser = None;
                if let [a, b] = &paths[..] {
                    self.compare_runs(a.clone(), b.clone());
                }
            }
            Some(file_browser::BrowserOutcome::Open(kind, paths)) => {
                self.browser = None;
                commands.push(Command::Open { kind, paths });
            }
            Some(file_browser::BrowserOutcome::Cancel) => self.browser = None,
            None => {}
        }
    }
}

/// While files are dragged over the window: a dark overlay saying they can be dropped.
pub(super) fn drop_overlay(ctx: &egui::Context) {
    if ctx.input(|i| !i.raw.hovered_files.is_empty()) {
        let painter = ctx.layer_painter(egui::LayerId::new(
            egui::Order::Foreground,
            egui::Id::unique("drop"),
        ));
        let r = ctx.content_rect();
        painter.rect_filled(r, 0.0, egui::Color32::from_black_alpha(160));
        painter.text(
            r.center(),
            egui::Align2::CENTER_CENTER,
            "Drop scan files or folders to open",
            egui::FontId::proportional(24.0),
            egui::Color32::WHITE,
        );
    }
}

/// Minimal executor for rfd's async dialog (it resolves on its own thread).
fn block_on<F: std::future::Future>(fut: F) -> F::Output {
    use std::task::{Context, Poll, Wake, Waker};
    struct ThreadWaker(std::thread::Thread);
    impl Wake for ThreadWaker {
        fn wake(self: Arc<Self>) {
            self.0.unpark();
        }
    }
    let waker = Waker::from(Arc::new(ThreadWaker(std::thread::current())));
    let mut cx = Context::from_waker(&waker);
    let mut fut = std::pin::pin!(fut);
    loop {
        match fut.as_mut().poll(&mut cx) {
            Poll::Ready(v) => return v,
            Poll::Pending => std::thread::park(),
        }
    }
}
