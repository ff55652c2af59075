//! Without a usable EGL library, headless rendering must fail with a clear error, not panic.
//! The check runs in a child process whose loader finds a broken libEGL.so.1 first.
#![cfg(feature = "gui")]

use std::process::Command;

const CHILD: &str = "CGENREG_NO_EGL_CHILD";

#[test]
fn screenshot_without_egl_is_a_clear_error() {
    if std::env::var_os(CHILD).is_some() {
        let out = std::path::PathBuf::from(std::env::var(CHILD).unwrap());
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
        println!("CHILD-OK: {err}");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // glutin tries libEGL.so.1 then libEGL.so
    for name in ["libEGL.so.1", "libEGL.so"] {
        std::fs::write(dir.path().join(name), b"not a library").unwrap();
    }
    let out = dir.path().join("x.png");
    let exe = std::env::current_exe().unwrap();
    let o = Command::new(exe)
        .args([
            "--exact",
            crate::common::test_name(module_path!(), "screenshot_without_egl_is_a_clear_error")
                .as_str(),
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD, &out)
        .env("LD_LIBRARY_PATH", dir.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success() && stdout.contains("CHILD-OK"),
        "child failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
}
