//! Without any EGL vendor, headless rendering must fail with a clear error, not panic.
//! (Own test binary: the EGL library is loaded once per process.)
#![cfg(feature = "gui")]

#[test]
fn screenshot_without_egl_is_a_clear_error() {
    // glvnd reads this before loading any vendor: point it at nothing.
    std::env::set_var(
        "__EGL_VENDOR_LIBRARIES_FILENAMES",
        "/nonexistent/egl_vendor.json",
    );
    std::env::set_var("__EGL_VENDOR_LIBRARIES_DIRS", "/nonexistent");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.png");
    let model = cgenreg::app::InspectorModel::demo();
    let r = cgenreg::app::headless::render_screenshot(
        &model,
        cgenreg::app::Panel::View3d,
        (320, 200),
        &out,
    );
    let err = r.expect_err("rendering without EGL must fail");
    assert!(err.contains("EGL"), "error should name EGL: {err}");
    assert!(!out.exists());
}
