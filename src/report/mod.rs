//! Run files read back: the typed rows of a `cgenreg bench --json` output and their comparison
//! (`cgenreg diff`, the inspector's Compare tab). A floor above `pipeline` (a run's header holds
//! its `RegisterParams`), below the CLI and the app.

pub mod bench_file;
pub mod compare;
pub mod labels;
