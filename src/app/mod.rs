//! The inspector GUI (in progress).
