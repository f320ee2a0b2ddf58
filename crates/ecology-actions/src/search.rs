//! The search engines: greedy best-first search (with preferred operators),
//! eager or lazy, A* and weighted A*, as loops of expansion steps over an
//! arena of nodes.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use crate::heuristic::Heuristic;
use crate::landmarks::LandmarkCount;
use crate::task::{AtomId, OpId, State, Task};

/// States stored once, flat, with an open-addressing hash index of node
/// ids: node `i` has state `i`. Per state: its words and at most two `u32`
/// slots, nothing else (no stored hash, no chain links).
#[derive(Debug, Default)]
pub(crate) struct Registry {
    pub(crate) words: usize,
    len: usize,
    data: Vec<u64>,
    /// Node ids by hash, linear probing, at most half full; `NONE` is empty.
    slots: Vec<u32>,
}

fn hash_words(words: &[u64]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &w in words {
        h = (h ^ w).wrapping_mul(0x0000_0100_0000_01b3).rotate_left(29);
        h = h.wrapping_mul(0x9e37_79b9_7f4a_7c15);
    }
    h
}

impl Registry {
    /// An empty registry of states of `words` words.
    pub(crate) fn new(words: usize) -> Registry {
        Registry {
            words,
            ..Registry::default()
        }
    }

    /// How many states are stored.
    pub(crate) fn len(&self) -> usize {
        self.len
    }

    pub(crate) fn get(&self, id: u32) -> &[u64] {
        let start = id as usize * self.words;
        &self.data[start..start + self.words]
    }

    /// The slot to look for `state` in first: the hash's high bits, which
    /// the final multiplication mixes best.
    fn home(&self, state: &[u64]) -> usize {
        let bits = self.slots.len().trailing_zeros();
        (hash_words(state) >> (64 - bits)) as usize
    }

    fn grow(&mut self) {
        let capacity = (self.slots.len() * 2).max(1024);
        self.slots = vec![NONE; capacity];
        let mask = capacity - 1;
        for id in 0..self.len as u32 {
            let mut i = self.home(self.get(id));
            while self.slots[i] != NONE {
                i = (i + 1) & mask;
            }
            self.slots[i] = id;
        }
    }

    /// The node of `state`, inserting it as node `len` if new; `true` if new.
    pub(crate) fn insert(&mut self, state: &[u64]) -> (u32, bool) {
        if (self.len + 1) * 2 > self.slots.len() {
            self.grow();
        }
        let mask = self.slots.len() - 1;
        let mut i = self.home(state);
        loop {
            let id = self.slots[i];
            if id == NONE {
                break;
            }
            if self.get(id) == state {
                return (id, false);
            }
            i = (i + 1) & mask;
        }
        let id = self.len as u32;
        self.data.extend_from_slice(state);
        self.slots[i] = id;
        self.len += 1;
        (id, true)
    }
}

const NONE: u32 = u32::MAX;

/// What a search keeps per state: 24 bytes (whether it is closed is a
/// separate bit vector).
#[derive(Debug, Clone, Copy)]
struct Node {
    g: u64,
    /// `DEAD`: a dead end.
    h: u64,
    parent: u32,
    op: u32,
}

/// The `h` of a dead end.
const DEAD: u64 = u64::MAX;

/// Which algorithm runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Algorithm {
    /// Every successor evaluated when generated.
    Greedy { preferred: bool },
    /// Successors wait under their parent's value and are evaluated when
    /// taken from the queue (LAMA's search): one evaluation per expansion
    /// instead of one per successor.
    LazyGreedy { preferred: bool },
    /// Best-first on `g + weight * h`: A* with weight 1.
    AStar { weight: u64 },
}

impl Algorithm {
    fn weight(self) -> Option<u64> {
        match self {
            Algorithm::AStar { weight } => Some(weight),
            Algorithm::Greedy { .. } | Algorithm::LazyGreedy { .. } => None,
        }
    }

    fn preferred(self) -> bool {
        match self {
            Algorithm::Greedy { preferred } | Algorithm::LazyGreedy { preferred } => preferred,
            Algorithm::AStar { .. } => false,
        }
    }
}

/// The result of one step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum StepResult {
    Continue,
    Solved(u32),
    Exhausted,
}

/// A queue entry, smallest first. Eager search: (h, 0, node, 0); A*:
/// (g + w h, h, node, 0); lazy search: (parent's h, order of insertion,
/// parent, operator). Remaining ties go to the older node.
type Entry = Reverse<(u64, u64, u32, u32)>;

/// How much a new best estimate favours the preferred queues in lazy
/// search: as in LAMA, they are taken about this many times in a row.
/// Eager search does not boost (nor does Fast Downward's by default): it
/// evaluates every successor, so its preferred queue already holds the
/// best of them, and a boost would keep it on a plateau of preferred
/// states long after the other queue holds better ones (parking: 13,011
/// expansions with a boost, 120 without).
const BOOST: i64 = 1000;

/// The open lists: for each heuristic one of every state and one of the
/// states reached by preferred operators, taken in turn as Fast Downward's
/// alternation list does: the non-empty list taken least often (less the
/// boosts of the preferred ones) goes next.
#[derive(Debug, Default)]
struct Queues {
    lists: Vec<BinaryHeap<Entry>>,
    taken: Vec<i64>,
}

impl Queues {
    fn new(heuristics: usize) -> Queues {
        Queues {
            lists: (0..2 * heuristics).map(|_| BinaryHeap::new()).collect(),
            taken: vec![0; 2 * heuristics],
        }
    }

    fn push(&mut self, heuristic: usize, preferred: bool, entry: Entry) {
        if preferred {
            self.lists[2 * heuristic + 1].push(entry);
        }
        self.lists[2 * heuristic].push(entry);
    }

    /// After progress: the preferred lists go first for a while.
    fn boost(&mut self) {
        for taken in self.taken.iter_mut().skip(1).step_by(2) {
            *taken -= BOOST;
        }
    }

    fn pop(&mut self) -> Option<Entry> {
        let next = (0..self.lists.len())
            .filter(|&i| !self.lists[i].is_empty())
            .min_by_key(|&i| self.taken[i])?;
        self.taken[next] += 1;
        self.lists[next].pop()
    }
}

pub(crate) struct Engine<'t> {
    task: &'t Task,
    excluded: Vec<bool>,
    heuristic: Box<dyn Heuristic + 't>,
    /// LAMA's second heuristic, beside the first, when asked for; its
    /// value for each node is in `landmark_h`.
    landmarks: Option<LandmarkCount>,
    landmark_h: Vec<u64>,
    algorithm: Algorithm,
    registry: Registry,
    nodes: Vec<Node>,
    closed: Vec<bool>,
    queues: Queues,
    /// Lazy search: successors queued so far (ties go to the older), and
    /// whether the initial node was expanded.
    queued: u64,
    started: bool,
    /// The best value of each heuristic so far: a new one is progress.
    best: [u64; 2],
    scratch: State,
    preferred: Vec<OpId>,
    sink: Vec<OpId>,
    successors: Vec<OpId>,
    pub(crate) expanded: u64,
    pub(crate) generated: u64,
    pub(crate) evaluated: u64,
    pub(crate) initial_h: Option<u64>,
    /// Paths that cost this much or more are pruned (eager search and A*):
    /// the cost of a plan already found, which only a cheaper one beats.
    pub(crate) bound: u64,
    /// A* without weight: the largest `g + h` taken from the queue so far.
    /// With an admissible heuristic no plan costs less (the cheapest plan
    /// always has a node waiting whose `g + h` is at most its cost).
    pub(crate) floor: u64,
    /// The atoms some operator the search uses reads (positively or
    /// negatively), or the goal names, as a mask of state words. Every state
    /// is stored without the others: they can change nothing that follows,
    /// so states that differ only in them are one state, as Fast Downward's
    /// translator drops such variables (visitall's cells visited but not in
    /// the goal: 102,747 expansions of A* with them, 8,713 without, on
    /// visitall-opt14 p-05-7). `None` when every atom is read.
    relevant: Option<Vec<u64>>,
}

/// The mask of atoms that `task`'s operators other than the `excluded`
/// ones read, or its goal names (see [`Engine::relevant`]); `None` when
/// that is every atom, so that most tasks pay nothing per state.
fn relevant_atoms(task: &Task, excluded: &[bool]) -> Option<Vec<u64>> {
    let mut mask = State::empty(task.atom_count());
    for (i, o) in task.operators().iter().enumerate() {
        if excluded.get(i).copied().unwrap_or(false) {
            continue;
        }
        for &a in o.pre.iter().chain(&o.pre_neg).chain(&o.observe) {
            mask.set(a);
        }
    }
    for &a in task.goal().iter().chain(task.goal_neg()) {
        mask.set(a);
    }
    let all = (0..task.atom_count()).all(|a| mask.holds(AtomId(a as u32)));
    (!all).then_some(mask.words)
}

impl std::fmt::Debug for Engine<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Engine")
            .field("heuristic", &self.heuristic.name())
            .field("landmarks", &self.landmarks.is_some())
            .field("algorithm", &self.algorithm)
            .field("expanded", &self.expanded)
            .finish_non_exhaustive()
    }
}

impl<'t> Engine<'t> {
    pub(crate) fn new(
        task: &'t Task,
        initial: &State,
        excluded: Vec<bool>,
        heuristic: Box<dyn Heuristic + 't>,
        landmarks: Option<LandmarkCount>,
        algorithm: Algorithm,
    ) -> Engine<'t> {
        let relevant = relevant_atoms(task, &excluded);
        let mut engine = Engine {
            task,
            excluded,
            heuristic,
            queues: Queues::new(if landmarks.is_some() { 2 } else { 1 }),
            landmarks,
            landmark_h: Vec::new(),
            algorithm,
            registry: Registry {
                words: initial.words.len(),
                ..Registry::default()
            },
            nodes: Vec::new(),
            closed: Vec::new(),
            queued: 0,
            started: false,
            best: [u64::MAX; 2],
            scratch: initial.clone(),
            preferred: Vec::new(),
            sink: Vec::new(),
            successors: Vec::new(),
            expanded: 0,
            generated: 0,
            evaluated: 0,
            initial_h: None,
            bound: u64::MAX,
            floor: 0,
            relevant,
        };
        engine.scratch.words.copy_from_slice(&initial.words);
        engine.forget_irrelevant();
        engine.registry.insert(&engine.scratch.words);
        let mut preferred = Vec::new();
        let h = engine.make_node(NONE, NONE, 0, &mut preferred);
        engine.initial_h = h;
        // Lazy search queues the initial node's successors when it starts.
        if h.is_some() && !matches!(algorithm, Algorithm::LazyGreedy { .. }) {
            engine.push(0, 0, false);
        }
        engine
    }

    /// Clears the atoms of `scratch` that can change nothing that follows.
    fn forget_irrelevant(&mut self) {
        if let Some(relevant) = &self.relevant {
            for (w, m) in self.scratch.words.iter_mut().zip(relevant) {
                *w &= m;
            }
        }
    }

    /// Makes `scratch`, just inserted in the registry, the next node, and
    /// evaluates it: its `h` (`None`: a dead end), with the preferred
    /// operators of its state in `preferred`. Records progress.
    fn make_node(
        &mut self,
        parent: u32,
        op: u32,
        g: u64,
        preferred: &mut Vec<OpId>,
    ) -> Option<u64> {
        self.evaluated += 1;
        preferred.clear();
        let h = self.heuristic.estimate(&self.scratch, preferred);
        self.nodes.push(Node {
            parent,
            op,
            g,
            h: h.unwrap_or(DEAD),
        });
        self.closed.push(false);
        if let Some(landmarks) = &mut self.landmarks {
            let from = (parent != NONE).then_some(parent);
            let lm = landmarks.push(from, &self.scratch);
            self.landmark_h.push(lm);
            if h.is_some() && lm < self.best[1] {
                self.best[1] = lm;
                self.progress(parent);
            }
        }
        let h = h?;
        if h < self.best[0] {
            self.best[0] = h;
            self.progress(parent);
        }
        Some(h)
    }

    /// A new best estimate, at a node reached from `parent`: lazy search
    /// boosts its preferred queues.
    fn progress(&mut self, parent: u32) {
        if parent != NONE && matches!(self.algorithm, Algorithm::LazyGreedy { .. }) {
            self.queues.boost();
        }
    }

    /// Queues node `id` (eager search and A*).
    fn push(&mut self, id: u32, g: u64, preferred: bool) {
        let h = self.nodes[id as usize].h;
        let entry = match self.algorithm {
            Algorithm::AStar { weight } => {
                Reverse((g.saturating_add(h.saturating_mul(weight)), h, id, 0))
            }
            // Among states of equal h, the older first, as in Fast
            // Downward's open lists (cheapest first kept greedy search far
            // longer on some plateaus: childsnack-opt14 pfile03-2).
            Algorithm::Greedy { .. } | Algorithm::LazyGreedy { .. } => Reverse((h, 0, id, 0)),
        };
        self.queues.push(0, preferred, entry);
        if self.landmarks.is_some() {
            let lm = self.landmark_h[id as usize];
            self.queues.push(1, preferred, Reverse((lm, 0, id, 0)));
        }
    }

    /// Whether the initial state is already a goal: the empty plan.
    pub(crate) fn initial_is_goal(&self) -> bool {
        self.task.is_goal(&State::from_words(self.registry.get(0)))
    }

    fn pop(&mut self) -> Option<u32> {
        loop {
            let Reverse((priority, _, id, _)) = self.queues.pop()?;
            if self.closed[id as usize] {
                continue;
            }
            let node = self.nodes[id as usize];
            if let Some(weight) = self.algorithm.weight()
                && node.g.saturating_add(node.h.saturating_mul(weight)) != priority
            {
                continue;
            }
            if self.algorithm.weight() == Some(1) {
                self.floor = self.floor.max(priority);
            }
            return Some(id);
        }
    }

    /// Lazy search: the next queued successor that reaches a new state,
    /// made a node and evaluated (with the preferred operators of its
    /// state in `preferred`); `Err` when the search ends (a goal, or
    /// nothing left).
    fn lazy_pop(&mut self, preferred: &mut Vec<OpId>) -> Result<u32, StepResult> {
        loop {
            let Some(Reverse((_, _, parent, op))) = self.queues.pop() else {
                return Err(StepResult::Exhausted);
            };
            self.generated += 1;
            self.scratch
                .words
                .copy_from_slice(self.registry.get(parent));
            self.task.apply_in_place(&mut self.scratch, OpId(op));
            self.forget_irrelevant();
            let (child, is_new) = self.registry.insert(&self.scratch.words);
            if !is_new {
                continue;
            }
            let g = self.nodes[parent as usize]
                .g
                .saturating_add(self.task.operator(OpId(op)).cost);
            if self.make_node(parent, op, g, preferred).is_none() {
                continue;
            }
            if self.task.is_goal(&self.scratch) {
                return Err(StepResult::Solved(child));
            }
            return Ok(child);
        }
    }

    /// Lazy search: expands one node, queueing its successors unevaluated.
    fn lazy_step(&mut self, use_preferred: bool) -> StepResult {
        let mut preferred = std::mem::take(&mut self.preferred);
        let id = if self.started {
            match self.lazy_pop(&mut preferred) {
                Ok(id) => id,
                Err(done) => {
                    self.preferred = preferred;
                    return done;
                }
            }
        } else {
            // The initial node, evaluated already: its preferred operators.
            self.started = true;
            self.scratch.words.copy_from_slice(self.registry.get(0));
            preferred.clear();
            self.heuristic.estimate(&self.scratch, &mut preferred);
            0
        };
        preferred.sort_unstable();
        self.closed[id as usize] = true;
        self.expanded += 1;
        let h = self.nodes[id as usize].h;
        let lm = self.landmark_h.get(id as usize).copied();
        self.scratch.words.copy_from_slice(self.registry.get(id));
        let excluded = &self.excluded;
        let (queues, queued) = (&mut self.queues, &mut self.queued);
        self.task.for_each_applicable(&self.scratch, |op| {
            if excluded.get(op.index()).copied().unwrap_or(false) {
                return;
            }
            *queued += 1;
            let is_preferred = use_preferred && preferred.binary_search(&op).is_ok();
            queues.push(0, is_preferred, Reverse((h, *queued, id, op.0)));
            if let Some(lm) = lm {
                queues.push(1, is_preferred, Reverse((lm, *queued, id, op.0)));
            }
        });
        self.preferred = preferred;
        StepResult::Continue
    }

    /// Expands one node.
    pub(crate) fn step(&mut self) -> StepResult {
        if let Algorithm::LazyGreedy { preferred } = self.algorithm {
            return self.lazy_step(preferred);
        }
        let Some(id) = self.pop() else {
            return StepResult::Exhausted;
        };
        self.scratch.words.copy_from_slice(self.registry.get(id));
        if self.algorithm.weight().is_some() && self.task.is_goal(&self.scratch) {
            return StepResult::Solved(id);
        }
        self.closed[id as usize] = true;
        self.expanded += 1;
        let g = self.nodes[id as usize].g;
        let use_preferred = self.algorithm.preferred();
        let mut preferred = std::mem::take(&mut self.preferred);
        preferred.clear();
        if use_preferred {
            // Recomputed here rather than stored for every generated node.
            self.heuristic.estimate(&self.scratch, &mut preferred);
            preferred.sort_unstable();
        }
        let mut successors = std::mem::take(&mut self.successors);
        successors.clear();
        let excluded = &self.excluded;
        self.task.for_each_applicable(&self.scratch, |op| {
            if !excluded.get(op.index()).copied().unwrap_or(false) {
                successors.push(op);
            }
        });
        let mut sink = std::mem::take(&mut self.sink);
        // The parent stays in the registry: each child starts from there.
        let mut result = StepResult::Continue;
        for &op in &successors {
            self.generated += 1;
            let new_g = g.saturating_add(self.task.operator(op).cost);
            if new_g >= self.bound {
                continue;
            }
            self.scratch.words.copy_from_slice(self.registry.get(id));
            self.task.apply_in_place(&mut self.scratch, op);
            self.forget_irrelevant();
            let (child, is_new) = self.registry.insert(&self.scratch.words);
            if is_new {
                if self.make_node(id, op.0, new_g, &mut sink).is_none() {
                    continue;
                }
                if self.algorithm.weight().is_none() && self.task.is_goal(&self.scratch) {
                    result = StepResult::Solved(child);
                    break;
                }
                let is_preferred = preferred.binary_search(&op).is_ok();
                self.push(child, new_g, is_preferred);
            } else if self.algorithm.weight().is_some() {
                let node = &mut self.nodes[child as usize];
                if node.h != DEAD && new_g < node.g {
                    node.g = new_g;
                    node.parent = id;
                    node.op = op.0;
                    self.closed[child as usize] = false;
                    self.push(child, new_g, false);
                }
            }
        }
        self.sink = sink;
        self.preferred = preferred;
        self.successors = successors;
        result
    }

    /// The operators from the initial state to node `id`.
    pub(crate) fn path(&self, mut id: u32) -> Vec<OpId> {
        let mut ops = Vec::new();
        while self.nodes[id as usize].parent != NONE {
            ops.push(OpId(self.nodes[id as usize].op));
            id = self.nodes[id as usize].parent;
        }
        ops.reverse();
        ops
    }

    /// The heuristic, for another search.
    pub(crate) fn into_heuristic(self) -> Box<dyn Heuristic + 't> {
        self.heuristic
    }

    /// Whether the heuristic is admissible.
    pub(crate) fn is_admissible(&self) -> bool {
        self.heuristic.is_admissible()
    }

    /// States stored.
    pub(crate) fn states(&self) -> usize {
        self.nodes.len()
    }
}
