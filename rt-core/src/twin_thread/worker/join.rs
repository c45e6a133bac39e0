//! Where a planner-made plan joins the running one (issue 42 item 2, in part). A policy's
//! lookahead takes well under a millisecond, so its join point, `join_ahead_s` ahead of the
//! arm, is still ahead when its plan reaches the cycle. The planner's search takes up to its
//! budget (`planner_fallback.budget_s`, 0.25 s), longer than `join_ahead_s` (0.1 s): a join
//! point read from the report before the search lay behind the arm when the plan arrived, and
//! the cycle refused it as late — joining was in practice the policies' alone.
//!
//! So a joining search starts from the point the arm reaches after the search at the
//! latest: the newest report's next sample, plus `join_ahead_s`, plus the search budget.
//! After the search (and the smoothing and the shield check) the cycle's report is read
//! again: the plan is sent only while its join point still lies ahead of the arm by a margin;
//! a late one is not sent (the cycle would refuse it) and planning is due again, from the
//! report as it is then.

use super::{Lookahead, TwinWorker};
use crate::cycle::Mode;
use crate::cycle::plan::{JoinPoint, MotionState};
use crate::cycle::shield::ShieldModel;

/// Samples (4 ms each at 250 Hz) a join point must still lie ahead of the arm when a
/// planner-made plan is handed over: the hand-over and the cycle's next period.
const JOIN_MARGIN_SAMPLES: usize = 5;

impl<L: Lookahead, M: ShieldModel<Scene = L::Scene>> TwinWorker<L, M> {
    /// The start and join point of a planner search joining the running plan `join.plan_id`
    /// (see the module docs): from the newest report, the next sample plus `join_ahead_s`
    /// plus the search budget; `None` when the running plan ends before it (or no longer
    /// runs): then the arm comes to rest first.
    pub(super) fn join_for_search(&mut self, join: JoinPoint) -> Option<(MotionState, JoinPoint)> {
        self.take_reports();
        let r = self.cycle.report?;
        if r.mode != Mode::Following || r.plan_id != join.plan_id {
            return None;
        }
        let index = r.next_index + self.settings.join_ahead + self.settings.search_lead;
        let (plan, _) = self.live_plan(join.plan_id)?;
        (index < plan.len()).then(|| {
            (
                plan.sample(index),
                JoinPoint {
                    plan_id: join.plan_id,
                    index,
                },
            )
        })
    }

    /// After a search: whether its plan, joining at `join`, still reaches the cycle in time
    /// (the report read now); when not, planning is due again.
    pub(super) fn join_in_time(&mut self, join: Option<JoinPoint>) -> bool {
        let Some(join) = join else {
            return true;
        };
        self.take_reports();
        let in_time = self.cycle.report.is_some_and(|r| {
            r.mode == Mode::Following
                && r.plan_id == join.plan_id
                && r.next_index + JOIN_MARGIN_SAMPLES <= join.index
        });
        if !in_time {
            self.planning.request();
        }
        in_time
    }
}
