//! The one loop over many pairs, shared by the CLI's `bench`, `generate` and `study` runs
//! (`shard::run_pending`) and the inspector's "Run all" and settings comparison: items in
//! order, an optional cancel flag checked before each, a hook before and after each, each item
//! run under [`catch_panic`](crate::error::catch_panic) and timed. What an item is, what it
//! produces and what is done with it stay with the caller.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crate::error::Result;

/// How a loop over items ended.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LoopEnd {
    /// Items that ran (each one handed to the "after" hook), counted from the first.
    pub ran: usize,
    /// Stopped by the cancel flag before every item ran.
    pub cancelled: bool,
}

/// Runs `items` in order on the caller's `state`. Before each item the cancel flag (if any) is
/// read: once set, the loop stops there and says it was cancelled; an item that started always
/// finishes. Per item: `before(state, index, item)`, then `run(state, index, item)` under
/// [`catch_panic`](crate::error::catch_panic) (a panic becomes
/// [`Error::Panicked`](crate::Error::Panicked)), timed, then `after(state, index, item, result,
/// elapsed)`. An error does not stop the loop: `after` decides what it means.
///
/// The hooks share `state` (passed to each) since they all need it mutably: a worker, a log,
/// a progress record.
pub fn run_items<S, I, T>(
    state: &mut S,
    items: &[I],
    cancel: Option<&AtomicBool>,
    mut before: impl FnMut(&mut S, usize, &I),
    mut run: impl FnMut(&mut S, usize, &I) -> Result<T>,
    mut after: impl FnMut(&mut S, usize, &I, Result<T>, Duration),
) -> LoopEnd {
    let mut end = LoopEnd::default();
    for (index, item) in items.iter().enumerate() {
        if cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
            end.cancelled = true;
            break;
        }
        before(state, index, item);
        let t = Instant::now();
        let r = crate::error::catch_panic(|| run(state, index, item));
        let elapsed = t.elapsed();
        after(state, index, item, r, elapsed);
        end.ran += 1;
    }
    end
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::Error;

    /// What the hooks saw, in the order they were called.
    #[derive(Debug, PartialEq)]
    enum Call {
        Before(usize, &'static str),
        Run(usize, &'static str),
        After(usize, &'static str, std::result::Result<u32, String>),
    }

    fn record(
        items: &[&'static str],
        cancel: Option<&AtomicBool>,
        run: impl Fn(usize, &str) -> Result<u32>,
        cancel_after: Option<usize>,
    ) -> (LoopEnd, Vec<Call>) {
        let mut calls = Vec::new();
        let end = run_items(
            &mut calls,
            items,
            cancel,
            |c, i, &id| c.push(Call::Before(i, id)),
            |c, i, &id| {
                c.push(Call::Run(i, id));
                run(i, id)
            },
            |c, i, &id, r, _| {
                c.push(Call::After(i, id, r.map_err(|e| e.to_string())));
                if cancel_after == Some(i) {
                    if let Some(flag) = cancel {
                        flag.store(true, Ordering::Relaxed);
                    }
                }
            },
        );
        (end, calls)
    }

    #[test]
    fn items_run_in_order_with_hooks_around_each() {
        let (end, calls) = record(&["p0", "p1", "p2"], None, |i, _| Ok(10 * i as u32), None);
        assert_eq!(
            end,
            LoopEnd {
                ran: 3,
                cancelled: false
            }
        );
        assert_eq!(
            calls,
            vec![
                Call::Before(0, "p0"),
                Call::Run(0, "p0"),
                Call::After(0, "p0", Ok(0)),
                Call::Before(1, "p1"),
                Call::Run(1, "p1"),
                Call::After(1, "p1", Ok(10)),
                Call::Before(2, "p2"),
                Call::Run(2, "p2"),
                Call::After(2, "p2", Ok(20)),
            ]
        );
    }

    #[test]
    fn a_panicking_item_is_an_error_and_the_loop_goes_on() {
        let (end, calls) = record(
            &["p0", "p1", "p2"],
            None,
            |i, _| match i {
                1 => panic!("item {i} exploded"),
                2 => Err(Error::Invalid("no such pair".into())),
                _ => Ok(7),
            },
            None,
        );
        assert_eq!(end.ran, 3);
        assert!(!end.cancelled);
        let afters: Vec<&Call> = calls
            .iter()
            .filter(|c| matches!(c, Call::After(..)))
            .collect();
        assert_eq!(afters.len(), 3, "{calls:?}");
        assert_eq!(afters[0], &Call::After(0, "p0", Ok(7)));
        match afters[1] {
            Call::After(1, "p1", Err(e)) => assert!(e.contains("item 1 exploded"), "{e}"),
            c => panic!("expected p1's panic as an error, got {c:?}"),
        }
        match afters[2] {
            Call::After(2, "p2", Err(e)) => assert!(e.contains("no such pair"), "{e}"),
            c => panic!("expected p2's error, got {c:?}"),
        }
    }

    #[test]
    fn a_panic_is_reported_as_panicked() {
        let mut got = None;
        let end = run_items(
            &mut got,
            &[()],
            None,
            |_, _, _| {},
            |_, _, _| -> Result<()> { panic!("boom") },
            |g, _, _, r, _| *g = Some(r),
        );
        assert_eq!(end.ran, 1);
        assert!(
            matches!(&got, Some(Err(Error::Panicked(m))) if m.contains("boom")),
            "{got:?}"
        );
    }

    #[test]
    fn cancel_set_by_a_hook_stops_before_the_next_item() {
        let flag = AtomicBool::new(false);
        let (end, calls) = record(
            &["p0", "p1", "p2", "p3"],
            Some(&flag),
            |_, _| Ok(1),
            Some(1),
        );
        assert_eq!(
            end,
            LoopEnd {
                ran: 2,
                cancelled: true
            }
        );
        // p1 finished (its after hook set the flag); p2 never started
        assert_eq!(calls.last(), Some(&Call::After(1, "p1", Ok(1))));
        assert_eq!(calls.len(), 6, "{calls:?}");
    }

    #[test]
    fn cancel_set_in_before_lets_that_item_finish() {
        let flag = AtomicBool::new(false);
        let mut calls = Vec::new();
        let end = run_items(
            &mut calls,
            &["p0", "p1", "p2"],
            Some(&flag),
            |c: &mut Vec<String>, i, id| {
                c.push(format!("before {i} {id}"));
                if i == 1 {
                    flag.store(true, Ordering::Relaxed);
                }
            },
            |_, _, _| Ok(()),
            |c, i, id, _, _| c.push(format!("after {i} {id}")),
        );
        assert_eq!(
            end,
            LoopEnd {
                ran: 2,
                cancelled: true
            }
        );
        assert_eq!(
            calls,
            vec!["before 0 p0", "after 0 p0", "before 1 p1", "after 1 p1"]
        );
    }

    #[test]
    fn a_flag_set_before_the_loop_runs_nothing_and_an_empty_loop_is_not_cancelled() {
        let flag = AtomicBool::new(true);
        let (end, calls) = record(&["p0"], Some(&flag), |_, _| Ok(1), None);
        assert_eq!(
            end,
            LoopEnd {
                ran: 0,
                cancelled: true
            }
        );
        assert!(calls.is_empty(), "{calls:?}");
        let (end, _) = record(&[], Some(&flag), |_, _| Ok(1), None);
        assert_eq!(end, LoopEnd::default());
    }

    #[test]
    fn elapsed_is_the_item_s_time() {
        let mut seen = Vec::new();
        run_items(
            &mut seen,
            &[0u64, 30],
            None,
            |_, _, _| {},
            |_, _, ms| {
                std::thread::sleep(Duration::from_millis(*ms));
                Ok(())
            },
            |s, _, _, _, t| s.push(t),
        );
        assert_eq!(seen.len(), 2);
        assert!(seen[1] >= Duration::from_millis(30), "{seen:?}");
    }
}
