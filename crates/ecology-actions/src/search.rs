//! The search engines: greedy best-first search (with preferred operators),
//! eager or lazy, A* and weighted A*, as loops of expansion steps over an
//! arena of nodes.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use crate::heuristic::Heuristic;
use crate::task::{OpId, State, Task};

/// States stored once, flat, with an open-addressing hash index of node
/// ids: node `i` has state `i`. Per state: its words and at most two `u32`
/// slots, nothing else (no stored hash, no chain links).
#[derive(Debug, Default)]
struct Registry {
    words: usize,
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
    fn get(&self, id: u32) -> &[u64] {
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
    fn insert(&mut self, state: &[u64]) -> (u32, bool) {
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
}

/// The result of one step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum StepResult {
    Continue,
    Solved(u32),
    Exhausted,
}

pub(crate) struct Engine<'t> {
    task: &'t Task,
    excluded: Vec<bool>,
    heuristic: Box<dyn Heuristic + 't>,
    algorithm: Algorithm,
    registry: Registry,
    nodes: Vec<Node>,
    closed: Vec<bool>,
    /// (priority, tie-break, node): the tie-break is h under A* and g under
    /// greedy search, then the older node first.
    open: BinaryHeap<Reverse<(u64, u64, u32)>>,
    preferred_open: BinaryHeap<Reverse<(u64, u64, u32)>>,
    /// Lazy search: (parent's h, order of insertion, parent, operator).
    lazy_open: BinaryHeap<Reverse<(u64, u64, u32, u32)>>,
    lazy_preferred: BinaryHeap<Reverse<(u64, u64, u32, u32)>>,
    /// Lazy search: successors queued so far (ties go to the older), and
    /// whether the initial node was expanded.
    queued: u64,
    started: bool,
    /// Expansions left from the preferred queue before alternating again.
    boost: u64,
    best_h: u64,
    turn: bool,
    scratch: State,
    preferred: Vec<OpId>,
    successors: Vec<OpId>,
    pub(crate) expanded: u64,
    pub(crate) generated: u64,
    pub(crate) evaluated: u64,
    pub(crate) initial_h: Option<u64>,
}

impl std::fmt::Debug for Engine<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Engine")
            .field("heuristic", &self.heuristic.name())
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
        algorithm: Algorithm,
    ) -> Engine<'t> {
        let mut engine = Engine {
            task,
            excluded,
            heuristic,
            algorithm,
            registry: Registry {
                words: initial.words.len(),
                ..Registry::default()
            },
            nodes: Vec::new(),
            closed: Vec::new(),
            open: BinaryHeap::new(),
            preferred_open: BinaryHeap::new(),
            lazy_open: BinaryHeap::new(),
            lazy_preferred: BinaryHeap::new(),
            queued: 0,
            started: false,
            boost: 0,
            best_h: u64::MAX,
            turn: false,
            scratch: initial.clone(),
            preferred: Vec::new(),
            successors: Vec::new(),
            expanded: 0,
            generated: 0,
            evaluated: 0,
            initial_h: None,
        };
        let (id, _) = engine.registry.insert(&initial.words);
        let h = engine.evaluate(initial);
        engine.initial_h = h;
        engine.nodes.push(Node {
            parent: NONE,
            op: NONE,
            g: 0,
            h: h.unwrap_or(DEAD),
        });
        engine.closed.push(false);
        if let Some(h) = h {
            engine.best_h = h;
            engine.push(id, 0, h, false);
        }
        engine
    }

    fn evaluate(&mut self, state: &State) -> Option<u64> {
        self.evaluated += 1;
        self.preferred.clear();
        let mut sink = Vec::new();
        self.heuristic.estimate(state, &mut sink)
    }

    fn push(&mut self, id: u32, g: u64, h: u64, preferred: bool) {
        let entry = match self.algorithm {
            Algorithm::AStar { weight } => {
                Reverse((g.saturating_add(h.saturating_mul(weight)), h, id))
            }
            // Among states of equal h, the one reached more cheaply first.
            Algorithm::Greedy { .. } | Algorithm::LazyGreedy { .. } => Reverse((h, g, id)),
        };
        if preferred {
            self.preferred_open.push(entry);
        }
        self.open.push(entry);
    }

    /// Whether the initial state is already a goal: the empty plan.
    pub(crate) fn initial_is_goal(&self) -> bool {
        self.task.is_goal(&State::from_words(self.registry.get(0)))
    }

    /// Whether to take the next node from the preferred queue (when it has
    /// any): while boosted after progress, else every other time.
    fn take_preferred(&mut self, has_preferred: bool) -> bool {
        let yes = has_preferred && (self.boost > 0 || self.turn);
        self.turn = !self.turn;
        if yes {
            self.boost = self.boost.saturating_sub(1);
        }
        yes
    }

    fn pop(&mut self) -> Option<u32> {
        loop {
            let entry = if self.take_preferred(!self.preferred_open.is_empty()) {
                self.preferred_open.pop()
            } else {
                self.open.pop()
            };
            let Reverse((priority, _, id)) = match entry {
                Some(e) => e,
                None if self.open.is_empty() && self.preferred_open.is_empty() => return None,
                None => continue,
            };
            if self.closed[id as usize] {
                continue;
            }
            let node = self.nodes[id as usize];
            if let Some(weight) = self.algorithm.weight()
                && node.g.saturating_add(node.h.saturating_mul(weight)) != priority
            {
                continue;
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
            let entry = if self.take_preferred(!self.lazy_preferred.is_empty()) {
                self.lazy_preferred.pop()
            } else {
                self.lazy_open.pop()
            };
            let Reverse((_, _, parent, op)) = match entry {
                Some(e) => e,
                None if self.lazy_open.is_empty() && self.lazy_preferred.is_empty() => {
                    return Err(StepResult::Exhausted);
                }
                None => continue,
            };
            self.generated += 1;
            self.scratch
                .words
                .copy_from_slice(self.registry.get(parent));
            self.task.apply_in_place(&mut self.scratch, OpId(op));
            let (child, is_new) = self.registry.insert(&self.scratch.words);
            if !is_new {
                continue;
            }
            let g = self.nodes[parent as usize]
                .g
                .saturating_add(self.task.operator(OpId(op)).cost);
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
            let Some(h) = h else { continue };
            if self.task.is_goal(&self.scratch) {
                return Err(StepResult::Solved(child));
            }
            if h < self.best_h {
                self.best_h = h;
                self.boost += 1000;
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
            let state = self.scratch.clone();
            preferred.clear();
            self.heuristic.estimate(&state, &mut preferred);
            0
        };
        preferred.sort_unstable();
        self.closed[id as usize] = true;
        self.expanded += 1;
        let h = self.nodes[id as usize].h;
        self.scratch.words.copy_from_slice(self.registry.get(id));
        let excluded = &self.excluded;
        let (open, preferred_open, queued) = (
            &mut self.lazy_open,
            &mut self.lazy_preferred,
            &mut self.queued,
        );
        self.task.for_each_applicable(&self.scratch, |op| {
            if excluded.get(op.index()).copied().unwrap_or(false) {
                return;
            }
            *queued += 1;
            let entry = Reverse((h, *queued, id, op.0));
            if use_preferred && preferred.binary_search(&op).is_ok() {
                preferred_open.push(entry);
            }
            open.push(entry);
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
        let use_preferred = matches!(self.algorithm, Algorithm::Greedy { preferred: true });
        let mut preferred = Vec::new();
        if use_preferred {
            // Recomputed here rather than stored for every generated node.
            let state = self.scratch.clone();
            self.heuristic.estimate(&state, &mut preferred);
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
        // The parent stays in the registry: each child starts from there.
        let mut result = StepResult::Continue;
        for &op in &successors {
            self.generated += 1;
            self.scratch.words.copy_from_slice(self.registry.get(id));
            self.task.apply_in_place(&mut self.scratch, op);
            let new_g = g.saturating_add(self.task.operator(op).cost);
            let (child, is_new) = self.registry.insert(&self.scratch.words);
            if is_new {
                self.evaluated += 1;
                let h = self.heuristic.estimate(&self.scratch, &mut Vec::new());
                self.nodes.push(Node {
                    parent: id,
                    op: op.0,
                    g: new_g,
                    h: h.unwrap_or(DEAD),
                });
                self.closed.push(false);
                let Some(h) = h else { continue };
                if let Algorithm::Greedy { .. } = self.algorithm {
                    if self.task.is_goal(&self.scratch) {
                        result = StepResult::Solved(child);
                        break;
                    }
                    if h < self.best_h {
                        self.best_h = h;
                        self.boost += 1000;
                    }
                }
                let is_preferred = preferred.binary_search(&op).is_ok();
                self.push(child, new_g, h, is_preferred);
            } else if self.algorithm.weight().is_some() {
                let node = &mut self.nodes[child as usize];
                if node.h != DEAD && new_g < node.g {
                    let h = node.h;
                    node.g = new_g;
                    node.parent = id;
                    node.op = op.0;
                    self.closed[child as usize] = false;
                    self.push(child, new_g, h, false);
                }
            }
        }
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

    /// Whether the heuristic is admissible.
    pub(crate) fn is_admissible(&self) -> bool {
        self.heuristic.is_admissible()
    }

    /// States stored.
    pub(crate) fn states(&self) -> usize {
        self.nodes.len()
    }
}
