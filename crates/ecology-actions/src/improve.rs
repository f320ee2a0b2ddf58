//! Making a found plan cheaper without searching again: greedy action
//! elimination (Fink and Yang; Nakhost and Müller). Greedy best-first
//! search often wanders (in the blocks world, a block picked up and put
//! down again); removing such detours keeps the plan valid and never makes
//! it costlier.

use std::cmp::Reverse;
use std::collections::{BinaryHeap, VecDeque};

use crate::search::Registry;
use crate::task::{OpId, State, Task};

/// Removes from `ops`, first to last, each action whose removal (together
/// with the later actions that no longer apply without it) still reaches
/// the goal from `initial`: the plan gets shorter and, costs being
/// non-negative, no costlier. `ops` must be a plan from `initial`; the
/// result is one too. Quadratic in the plan's length.
pub(crate) fn eliminate_actions(task: &Task, initial: &State, ops: &mut Vec<OpId>) {
    // The state before `ops[i]`.
    let mut before = initial.clone();
    let mut state = initial.clone();
    let mut kept: Vec<OpId> = Vec::with_capacity(ops.len());
    let mut i = 0;
    while i < ops.len() {
        state.words.copy_from_slice(&before.words);
        kept.clear();
        for &op in &ops[i + 1..] {
            if task.applicable(&state, op) {
                task.apply_in_place(&mut state, op);
                kept.push(op);
            }
        }
        if task.is_goal(&state) {
            ops.truncate(i);
            ops.extend_from_slice(&kept);
            // `ops[i]` is now another action: try again from the same state.
        } else {
            task.apply_in_place(&mut before, ops[i]);
            i += 1;
        }
    }
}

/// The work of one transition of a neighbourhood round (a state copied,
/// an operator applied, the result looked up), in operators looked at for
/// successors.
const TRANSITION_WORK: u64 = 16;

/// The work of storing a new state, per word of state (kept, queued,
/// expanded later: large states make the graph slow to grow).
const STATE_WORD_WORK: u64 = 32;

/// The words of state a round stores at most, 256 MB, and the
/// transitions (8 bytes each).
const MAX_WORDS: usize = 32 << 20;

/// Plan neighbourhood graph search (Nakhost and Müller), one round: the
/// states of a plan and, breadth first from them, the states around them,
/// until the work of finding their successors reaches a limit; then the
/// cheapest path from the start to a goal through the transitions out of
/// the states expanded. The plan's own transitions are among them, so that
/// path never costs more than the plan. Detours that action elimination
/// cannot remove (a truck driving two roads where one would do) are
/// replaced here.
#[derive(Debug)]
pub(crate) struct Neighbourhood {
    registry: Registry,
    start: u32,
    /// States to expand, in breadth-first order.
    queue: VecDeque<u32>,
    /// Transitions out of state `i`: `edges[out[i].0..out[i].1]`.
    out: Vec<(u32, u32)>,
    edges: Vec<(OpId, u32)>,
    limit: u64,
    /// The plan's states, the first expanded whatever the limit, so that
    /// the plan's transitions are always in the graph.
    plan_states: u64,
    /// The work so far: operators looked at for successors,
    /// [`TRANSITION_WORK`] per transition and [`STATE_WORD_WORK`] per word
    /// of each new state.
    pub(crate) work: u64,
    scratch: State,
    child: State,
    ops: Vec<OpId>,
    pub(crate) expanded: u64,
    pub(crate) generated: u64,
}

impl Neighbourhood {
    /// A round around `plan` from `initial`, to do at most `limit` work
    /// (see `work`) once the plan's own states are expanded, and store at
    /// most 256 MB of states and 256 MB of transitions.
    pub(crate) fn new(task: &Task, initial: &State, plan: &[OpId], limit: u64) -> Neighbourhood {
        let mut registry = Registry::new(initial.words.len());
        let mut scratch = initial.clone();
        let mut queue = VecDeque::new();
        let (start, _) = registry.insert(&scratch.words);
        queue.push_back(start);
        for &op in plan {
            task.apply_in_place(&mut scratch, op);
            let (id, new) = registry.insert(&scratch.words);
            if new {
                queue.push_back(id);
            }
        }
        Neighbourhood {
            registry,
            start,
            plan_states: queue.len() as u64,
            queue,
            out: Vec::new(),
            edges: Vec::new(),
            limit,
            work: 0,
            child: initial.clone(),
            scratch,
            ops: Vec::new(),
            expanded: 0,
            generated: 0,
        }
    }

    /// States stored.
    pub(crate) fn states(&self) -> usize {
        self.registry.len()
    }

    /// Expands the next state, without the operators `skip` marks; false
    /// once the graph is complete.
    pub(crate) fn expand(&mut self, task: &Task, skip: &[bool]) -> bool {
        // At most 256 MB of states, and as much of transitions (8 bytes each).
        let full =
            self.registry.len() * self.registry.words >= MAX_WORDS || self.edges.len() >= MAX_WORDS;
        if (self.work >= self.limit && self.expanded >= self.plan_states) || full {
            return false;
        }
        let Some(id) = self.queue.pop_front() else {
            return false;
        };
        self.expanded += 1;
        self.scratch.words.copy_from_slice(self.registry.get(id));
        let ops = &mut self.ops;
        ops.clear();
        self.work += task.for_each_applicable_counted(&self.scratch, |op| {
            if !skip.get(op.index()).copied().unwrap_or(false) {
                ops.push(op);
            }
        });
        self.work += self.ops.len() as u64 * TRANSITION_WORK;
        let state_work = self.registry.words as u64 * STATE_WORD_WORK;
        let first = self.edges.len() as u32;
        for &op in &self.ops {
            self.generated += 1;
            self.child.words.copy_from_slice(&self.scratch.words);
            task.apply_in_place(&mut self.child, op);
            let (to, new) = self.registry.insert(&self.child.words);
            if new {
                self.queue.push_back(to);
                self.work += state_work;
            }
            self.edges.push((op, to));
        }
        if self.out.len() <= id as usize {
            self.out.resize(id as usize + 1, (0, 0));
        }
        self.out[id as usize] = (first, self.edges.len() as u32);
        true
    }

    /// The cheapest path from the start to a goal within the graph
    /// (Dijkstra), if the graph has a goal.
    pub(crate) fn cheapest(&mut self, task: &Task) -> Option<Vec<OpId>> {
        let n = self.registry.len();
        let mut dist = vec![u64::MAX; n];
        let mut parent: Vec<(u32, OpId)> = vec![(u32::MAX, OpId(0)); n];
        let mut heap = BinaryHeap::new();
        dist[self.start as usize] = 0;
        heap.push(Reverse((0u64, self.start)));
        while let Some(Reverse((d, id))) = heap.pop() {
            if d > dist[id as usize] {
                continue;
            }
            self.scratch.words.copy_from_slice(self.registry.get(id));
            if task.is_goal(&self.scratch) {
                let mut path = Vec::new();
                let mut at = id;
                while at != self.start {
                    let (p, op) = parent[at as usize];
                    path.push(op);
                    at = p;
                }
                path.reverse();
                return Some(path);
            }
            let (from, to) = self.out.get(id as usize).copied().unwrap_or((0, 0));
            for &(op, next) in &self.edges[from as usize..to as usize] {
                let nd = d.saturating_add(task.operator(op).cost);
                if nd < dist[next as usize] {
                    dist[next as usize] = nd;
                    parent[next as usize] = (id, op);
                    heap.push(Reverse((nd, next)));
                }
            }
        }
        None
    }
}
