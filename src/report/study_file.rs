//! A study's output (`cgenreg study k|prompt --json`, and `cgenreg merge` of its shards): the
//! report rebuilt from a run file's header (its parameters and settings) and records, and the
//! bytes written. The settings are part of the run's identity, so a merged run's report is
//! the one its shards would have written.

use crate::error::{Error, Result};
use crate::pipeline::shard::{RunFile, FAILED};
use crate::pipeline::study::{
    assemble_study, plan_study, SettingOutcome, StudyReport, StudySetting,
};
use crate::pipeline::RegisterParams;
use serde_json::{json, Value};

/// The settings as JSON (they are part of the run's identity, and `merge` rebuilds the
/// report from them).
pub fn settings_json(settings: &[StudySetting]) -> Value {
    Value::Array(
        settings
            .iter()
            .map(|s| match s {
                StudySetting::K(k) => json!({ "k": k }),
                StudySetting::Prompt { label, prompt } => {
                    json!({ "label": label, "prompt": prompt })
                }
            })
            .collect(),
    )
}

pub fn settings_from_json(v: &Value) -> Result<Vec<StudySetting>> {
    let bad = || Error::Invalid("a study run file without readable settings".into());
    v.as_array()
        .ok_or_else(bad)?
        .iter()
        .map(|s| {
            if let Some(k) = s.get("k").and_then(Value::as_u64) {
                Ok(StudySetting::K(k as usize))
            } else {
                Ok(StudySetting::Prompt {
                    label: s
                        .get("label")
                        .and_then(Value::as_str)
                        .ok_or_else(bad)?
                        .to_string(),
                    prompt: serde_json::from_value(s.get("prompt").cloned().unwrap_or_default())
                        .map_err(|_| bad())?,
                })
            }
        })
        .collect()
}

/// The report of a study run file (its settings and parameters are in the identity).
pub fn study_report(f: &RunFile) -> Result<StudyReport> {
    let p = &f.run.identity.params;
    let params: RegisterParams = serde_json::from_value(p["register"].clone())
        .map_err(|e| Error::Invalid(format!("a study run file's parameters: {e}")))?;
    let settings = settings_from_json(&p["settings"])?;
    let plan = plan_study(&params, &settings)?;
    let mut outcomes = Vec::new();
    for r in &f.records {
        let o: Vec<SettingOutcome> = if r.status == FAILED {
            let why = r.error.clone().unwrap_or_default();
            plan.rows
                .iter()
                .map(|row| match row.setting_skipped {
                    Some(_) => SettingOutcome::SettingSkipped,
                    None => SettingOutcome::Failed {
                        reason: why.clone(),
                    },
                })
                .collect()
        } else {
            serde_json::from_value(r.result["outcomes"].clone())
                .map_err(|e| Error::Invalid(format!("pair {}: not a study result: {e}", r.id)))?
        };
        outcomes.push((r.id.clone(), o));
    }
    let ids: Vec<String> = f.records.iter().map(|r| r.id.clone()).collect();
    Ok(assemble_study(&plan, &params, &ids, &outcomes))
}

/// Study output bytes for a run file: the report's fields plus `run` and `records`.
pub fn study_json(f: &RunFile) -> Result<Vec<u8>> {
    let rep = study_report(f)?;
    let mut v = serde_json::to_value(&rep)
        .map_err(|e| Error::Encode(format!("serialising the study: {e}")))?;
    v["run"] = serde_json::to_value(&f.run).unwrap_or_default();
    v["records"] = serde_json::to_value(&f.records).unwrap_or_default();
    serde_json::to_vec_pretty(&v).map_err(|e| Error::Encode(format!("serialising the study: {e}")))
}
