//! Best-first search over the set of chosen providers and their open inputs,
//! for domains of *provider shape* (issue 11).
//!
//! A domain has provider shape when, in the ground graph, every feasible
//! method alternative runs exactly one functionality and one task per input
//! of that functionality, each task wired by a channel to that input, and the
//! functionality's output is what the method's task provides. Ecologies of
//! shared cameras and costly links look like this. A configuration is then a
//! set of functionality instances (*providers*) plus, for each of their inputs
//! (*needs*), the provider feeding it: a provider serving two consumers is one
//! instance, paid once, its own inputs wired once — exactly what the tree
//! search's assembly makes of a decomposition whose shared subtrees agree.
//!
//! A search state is the set of chosen providers and the set of open needs;
//! `g` is exact (components plus channels so far). Expanding a state resolves
//! its lowest-numbered open need, one child per provider that can feed it.
//! Because the need resolved is a function of the state, every configuration
//! has exactly one path (so k-best lists need no duplicate check), and states
//! reached in different orders are recognised as one (kept at the cheapest
//! `g`) when looking for the optimum.
//!
//! The bound `h` is admissible: every open need will get its own channel (at
//! least its cheapest one); every task no chosen provider serves needs a new
//! provider, and so do the tasks all of its providers need (landmarks); a new
//! provider costs at least its own cost plus the cheapest channel into each of
//! its inputs; a landmark's open needs are fed either all by one new provider
//! or by at least two, whose second costs at least the cheapest provider. When
//! providers serve more than one task, landmarks count their maximum instead
//! of their sum.
//!
//! Domains not of this shape, or whose providers could feed each other in a
//! cycle, are searched by the decomposition tree search (`search`).
//!
//! `build` makes the search from the ground graph, in phases; this module
//! holds the search itself.

use std::cell::RefCell;
use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::hash::{Hash, Hasher};

use rustc_hash::{FxHashMap as HashMap, FxHasher};

use crate::compile::GInfo;
use crate::explain;
use crate::ground::{INFEASIBLE, ItemId};
use crate::model::Configuration;
use crate::search::Engine;

mod build;

const NONE: u32 = u32::MAX;

/// The caller's budget ran out before the provider search was built: the
/// search is cut, and finishes at once with nothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Cut;

/// Steps of a dive between two looks at the budget: each costs one bound per
/// provider of the information it wires, and a first dive wires a whole
/// configuration, which on large ecologies takes milliseconds.
const DIVE_STEPS_PER_CHECK: u64 = 8;

/// One way to resolve a need: an alternative of its task and the provider it runs.
#[derive(Debug, Clone, Copy)]
struct Opt {
    alt: u32,
    prov: u32,
    /// The channel's cost into the consumer.
    wire: u64,
}

#[derive(Debug)]
struct Prov {
    item: ItemId,
    peis: u32,
    cost: u64,
    /// Its needs are `first_need..first_need + needs.len()`.
    first_need: u32,
    /// Its inputs, in order, with the task that provides each.
    needs: Vec<(GInfo, ItemId)>,
    /// Other providers on the same component.
    conflicts: Vec<u32>,
    /// Its cost plus the cheapest channel into each input.
    w: u64,
    /// The tasks it can provide: a range of `Shared::serves`.
    serves: (u32, u32),
}

#[derive(Debug)]
struct Need {
    /// The consuming provider; `NONE` for the goal itself.
    consumer: u32,
    task: u32,
    /// Its options: a range of `Shared::opts`.
    opts: (u32, u32),
    min_wire: u64,
}

#[derive(Debug, Default)]
struct Task {
    item: ItemId,
    /// Feasible alternatives: (alternative, provider, and the range of the
    /// information it provides in `Shared::new`'s list).
    alts: Vec<(u32, u32, u32, u32)>,
    provs: Vec<u32>,
    /// Tasks that every provider of this one needs.
    common: Vec<u32>,
    /// The cheapest `w` among its providers.
    wmin: u64,
}

/// The children of one state: (opt index, added cost), and their states
/// back to back, reused from one expansion to the next.
#[derive(Default)]
struct Kids {
    info: Vec<(u32, u64)>,
    states: Vec<u64>,
}

impl Kids {
    fn state(&self, k: usize, words: usize) -> &[u64] {
        &self.states[k * words..(k + 1) * words]
    }
}

/// Buffers of the bound, kept between calls. Its lists are threaded through
/// arrays (a head per task, a link per provider or need), so building them
/// allocates nothing.
#[derive(Debug, Default)]
struct Scratch {
    /// Per task: a chosen provider serving it (`NONE`: none); when every
    /// provider serves one task, the head of the list of them all.
    serving: Vec<u32>,
    /// Per provider: the next chosen provider serving the same task.
    next_prov: Vec<u32>,
    /// Per task: the head of the list of its open needs (`NONE`: none).
    waiting: Vec<u32>,
    /// Per need: the next open need of the same task.
    next_need: Vec<u32>,
    landmark: Vec<bool>,
    work: Vec<usize>,
    /// One task's open needs, each with its cheapest chosen feeder.
    a: Vec<(u32, u64)>,
}

#[derive(Debug, Clone, Copy)]
struct Node {
    parent: u32,
    need: u32,
    opt: u32,
    g: u64,
    /// A dive expanded it: its children are pushed already.
    expanded: bool,
}

/// The provider-shape search; see the module docs.
#[derive(Debug)]
pub(crate) struct Shared {
    provs: Vec<Prov>,
    /// The tasks each provider serves, by provider, back to back.
    serves: Vec<u32>,
    needs: Vec<Need>,
    /// The needs' options, by need, back to back.
    opts: Vec<Opt>,
    tasks: Vec<Task>,
    /// The provider of each graph item, by item index (`NONE`: none).
    prov_of_item: Vec<u32>,
    /// Channel costs between PEIS indices, row: producer.
    chan: Vec<u64>,
    npeis: usize,
    /// Whether every provider serves at most one task (landmarks add up).
    additive: bool,
    pwords: usize,
    words: usize,
    count: usize,
    nodes: Vec<Node>,
    /// States of the nodes, `words` words each: chosen providers, then open needs.
    states: Vec<u64>,
    open: BinaryHeap<(Reverse<u64>, u64, Reverse<u32>)>,
    seen: HashMap<u64, u32>,
    bound: u64,
    incumbent: Option<(u64, Vec<u32>)>,
    accepted: Vec<(u64, Vec<u32>)>,
    started: bool,
    scratch: RefCell<Scratch>,
    pub(crate) expanded: u64,
    pub(crate) generated: u64,
}

fn bit(words: &[u64], i: usize) -> bool {
    words[i / 64] >> (i % 64) & 1 == 1
}

fn set(words: &mut [u64], i: usize, on: bool) {
    if on {
        words[i / 64] |= 1 << (i % 64);
    } else {
        words[i / 64] &= !(1 << (i % 64));
    }
}

fn ones(words: &[u64]) -> impl Iterator<Item = usize> + '_ {
    words.iter().enumerate().flat_map(|(w, &x)| {
        let mut x = x;
        std::iter::from_fn(move || {
            if x == 0 {
                return None;
            }
            let b = x.trailing_zeros() as usize;
            x &= x - 1;
            Some(w * 64 + b)
        })
    })
}

impl Shared {
    /// The options of need `n`.
    fn opts_of(&self, n: usize) -> &[Opt] {
        let (from, to) = self.needs[n].opts;
        &self.opts[from as usize..to as usize]
    }

    fn wire(&self, from: u32, to: u32) -> u64 {
        let (a, b) = (
            self.provs[from as usize].peis as usize,
            self.provs[to as usize].peis as usize,
        );
        if a == b {
            0
        } else {
            self.chan[a * self.npeis + b]
        }
    }

    /// The admissible bound of a state (see the module docs).
    fn h(&self, state: &[u64]) -> u64 {
        let (chosen, open) = state.split_at(self.pwords);
        let nt = self.tasks.len();
        // Scratch buffers reused between calls: the bound runs once per child.
        let mut scratch = self.scratch.borrow_mut();
        let Scratch {
            serving,
            next_prov,
            waiting,
            next_need,
            landmark,
            work,
            a,
        } = &mut *scratch;
        serving.clear();
        serving.resize(nt, NONE);
        waiting.clear();
        waiting.resize(nt, NONE);
        landmark.clear();
        landmark.resize(nt, false);
        next_prov.resize(self.provs.len(), NONE);
        next_need.resize(self.needs.len(), NONE);
        work.clear();
        for p in ones(chosen) {
            let (from, to) = self.provs[p].serves;
            for &t in &self.serves[from as usize..to as usize] {
                next_prov[p] = serving[t as usize];
                serving[t as usize] = p as u32;
            }
        }
        let mut sum: u64 = 0;
        for n in ones(open) {
            let need = &self.needs[n];
            if need.min_wire == INFEASIBLE {
                return INFEASIBLE;
            }
            let t = need.task as usize;
            landmark[t] |= serving[t] == NONE;
            if self.additive {
                next_need[n] = waiting[t];
                waiting[t] = n as u32;
            } else {
                sum = sum.saturating_add(need.min_wire);
            }
        }
        work.extend((0..nt).filter(|&t| landmark[t]));
        while let Some(t) = work.pop() {
            for &u in &self.tasks[t].common {
                let u = u as usize;
                if serving[u] == NONE && !landmark[u] {
                    landmark[u] = true;
                    work.push(u);
                }
            }
        }
        if !self.additive {
            let most = (0..nt)
                .filter(|&t| landmark[t])
                .map(|t| self.tasks[t].wmin)
                .max();
            return sum.saturating_add(most.unwrap_or(0));
        }
        let into = |g: u32, n: u32| match self.needs[n as usize].consumer {
            NONE => 0,
            c => self.wire(g, c),
        };
        for t in 0..nt {
            let task = &self.tasks[t];
            if waiting[t] == NONE {
                if landmark[t] {
                    sum = sum.saturating_add(task.wmin);
                }
                continue;
            }
            // The needs are fed by chosen providers only (each at least its
            // cheapest chosen feeder, `a`), or some new provider `F` is added:
            // then each need costs its cheaper of a chosen feeder and `F`,
            // unless a second new provider (at least `wmin`) joins in.
            a.clear();
            let mut n = waiting[t];
            while n != NONE {
                let mut cheapest = INFEASIBLE;
                let mut g = serving[t];
                while g != NONE {
                    cheapest = cheapest.min(into(g, n));
                    g = next_prov[g as usize];
                }
                a.push((n, cheapest));
                n = next_need[n as usize];
            }
            let all_chosen = a.iter().fold(0u64, |s, &(_, x)| s.saturating_add(x));
            let cheapest: u64 = a
                .iter()
                .map(|&(n, a)| a.min(self.needs[n as usize].min_wire))
                .sum();
            let second = task.wmin.saturating_add(cheapest);
            // Providers come cheapest `w` first: stop once `w` alone is no better.
            let mut with_new = INFEASIBLE;
            for &f in &task.provs {
                let prov = &self.provs[f as usize];
                if prov.w >= with_new.min(all_chosen) {
                    break;
                }
                if bit(chosen, f as usize) {
                    continue;
                }
                let alone = a
                    .iter()
                    .fold(0u64, |s, &(n, a)| s.saturating_add(a.min(into(f, n))));
                with_new = with_new.min(prov.w.saturating_add(alone.min(second)));
            }
            let best = all_chosen.min(with_new);
            if best == INFEASIBLE {
                return INFEASIBLE;
            }
            sum = sum.saturating_add(best);
        }
        sum
    }

    /// The children of a state, into `kids`: (opt index, added cost), and
    /// their states back to back.
    fn children(&self, state: &[u64], need: usize, kids: &mut Kids) {
        kids.info.clear();
        kids.states.clear();
        for (o, opt) in self.opts_of(need).iter().enumerate() {
            let p = opt.prov as usize;
            let at = kids.states.len();
            kids.states.extend_from_slice(state);
            let (chosen, open) = kids.states[at..].split_at_mut(self.pwords);
            set(open, need, false);
            let mut add = opt.wire;
            if !bit(chosen, p) {
                let prov = &self.provs[p];
                if prov.conflicts.iter().any(|&q| bit(chosen, q as usize)) {
                    kids.states.truncate(at);
                    continue;
                }
                set(chosen, p, true);
                let first = prov.first_need as usize;
                for n in first..first + prov.needs.len() {
                    set(open, n, true);
                }
                add = add.saturating_add(prov.cost);
            }
            kids.info.push((o as u32, add));
        }
    }

    fn first_open(&self, state: &[u64]) -> Option<usize> {
        ones(&state[self.pwords..]).next()
    }

    /// Adds a node to the open list; `None` when its state was reached
    /// before at no higher cost.
    fn push(
        &mut self,
        parent: u32,
        need: u32,
        opt: u32,
        g: u64,
        f: u64,
        state: &[u64],
    ) -> Option<u32> {
        let id = self.nodes.len() as u32;
        if self.count == 1 {
            let mut hasher = FxHasher::default();
            state.hash(&mut hasher);
            let key = hasher.finish();
            match self.seen.get(&key) {
                Some(&old) if self.state(old) == state => {
                    if self.nodes[old as usize].g <= g {
                        return None;
                    }
                    self.seen.insert(key, id);
                }
                Some(_) => {} // A hash collision: keep both, unrecognised.
                None => {
                    self.seen.insert(key, id);
                }
            }
        }
        self.nodes.push(Node {
            parent,
            need,
            opt,
            g,
            expanded: false,
        });
        self.states.extend_from_slice(state);
        self.open.push((Reverse(f), g, Reverse(id)));
        self.generated += 1;
        Some(id)
    }

    fn state(&self, id: u32) -> &[u64] {
        let at = id as usize * self.words;
        &self.states[at..at + self.words]
    }

    fn choices(&self, mut id: u32) -> Vec<u32> {
        let mut choice = vec![NONE; self.needs.len()];
        while id != NONE {
            let node = self.nodes[id as usize];
            if node.need != NONE {
                choice[node.need as usize] = node.opt;
            }
            id = node.parent;
        }
        choice
    }

    /// Greedy descent from a node, cheapest `f` first; a new incumbent if better.
    /// Each step expands a node as the search would, pushing its children
    /// onto the open list, and marks it expanded, so that the search does not
    /// expand it again. Gives up after `limit` steps, each counted as an
    /// expansion, or when `over` (asked every [`DIVE_STEPS_PER_CHECK`] steps)
    /// says the budget ran out.
    fn dive(&mut self, from: u32, limit: u64, over: &dyn Fn() -> bool) {
        let mut id = from;
        let mut state = Vec::with_capacity(self.words);
        let mut kids = Kids::default();
        let mut steps = 0;
        loop {
            state.clear();
            state.extend_from_slice(self.state(id));
            let g = self.nodes[id as usize].g;
            let Some(need) = self.first_open(&state) else {
                if g < self.bound {
                    self.bound = g;
                    self.incumbent = Some((g, self.choices(id)));
                }
                return;
            };
            if steps == limit
                || (steps % DIVE_STEPS_PER_CHECK == DIVE_STEPS_PER_CHECK - 1 && over())
            {
                return;
            }
            steps += 1;
            // Each step of the dive counts against the node budget.
            self.nodes[id as usize].expanded = true;
            let Some(child) = self.expand(id, g, &state, need, true, &mut kids) else {
                return;
            };
            id = child;
        }
    }

    /// Expands node `id` (cost so far `g`, state `state`) on its open need
    /// `need`: pushes each child whose bound is finite (and, when `prune`,
    /// below the incumbent's cost). Returns the pushed child of least `f`
    /// (then of least option).
    fn expand(
        &mut self,
        id: u32,
        g: u64,
        state: &[u64],
        need: usize,
        prune: bool,
        kids: &mut Kids,
    ) -> Option<u32> {
        self.expanded += 1;
        self.children(state, need, kids);
        let mut best: Option<(u64, u32, u32)> = None;
        for (k, &(o, add)) in kids.info.iter().enumerate() {
            let s = kids.state(k, self.words);
            let cg = g.saturating_add(add);
            let h = self.h(s);
            if h == INFEASIBLE {
                continue;
            }
            let cf = cg.saturating_add(h);
            if prune && cf >= self.bound {
                continue;
            }
            if let Some(child) = self.push(id, need as u32, o, cg, cf, s)
                && best.is_none_or(|(bf, bo, _)| (cf, o) < (bf, bo))
            {
                best = Some((cf, o, child));
            }
        }
        best.map(|(_, _, child)| child)
    }

    /// Nothing chosen; the goal's need open.
    fn root_state(&self) -> Vec<u64> {
        let mut state = vec![0u64; self.words];
        set(&mut state[self.pwords..], 0, true);
        state
    }

    fn done(&self) -> bool {
        self.accepted.len() >= self.count || self.open.is_empty()
    }

    /// Runs at most `expansions` expansions; returns whether the search is
    /// over. Dives ask `over` now and then whether the budget ran out.
    pub(crate) fn step(&mut self, expansions: u64, over: &dyn Fn() -> bool) -> bool {
        let single = self.count == 1;
        if !self.started {
            self.started = true;
            let state = self.root_state();
            let h = self.h(&state);
            if h != INFEASIBLE {
                self.push(NONE, NONE, NONE, 0, h, &state);
                if single {
                    // A first configuration at once: anytime.
                    self.dive(0, expansions.max(1), over);
                }
            }
            return self.finalize();
        }
        let mut kids = Kids::default();
        let mut state = Vec::with_capacity(self.words);
        for done in 0..expansions {
            let Some((Reverse(f), _, Reverse(id))) = self.open.pop() else {
                break;
            };
            if single && f >= self.bound {
                self.open.clear();
                break;
            }
            if self.nodes[id as usize].expanded {
                continue; // A dive expanded it.
            }
            state.clear();
            state.extend_from_slice(self.state(id));
            if single {
                let mut hasher = FxHasher::default();
                state.hash(&mut hasher);
                if self
                    .seen
                    .get(&hasher.finish())
                    .is_some_and(|&best| best != id && self.state(best) == &state[..])
                {
                    continue; // Reached again more cheaply.
                }
            }
            let g = self.nodes[id as usize].g;
            let Some(need) = self.first_open(&state) else {
                // Complete: the cheapest left, by admissibility.
                self.accepted.push((g, self.choices(id)));
                if single {
                    self.bound = g;
                    self.incumbent = None;
                }
                if self.done() {
                    break;
                }
                continue;
            };
            self.expand(id, g, &state, need, single, &mut kids);
            if single
                && self.expanded % 4096 == 0
                && let Some(&(_, _, Reverse(top))) = self.open.peek()
            {
                // Anytime: look for something better below the best open node.
                self.dive(top, expansions - done, over);
            }
        }
        self.finalize()
    }

    fn finalize(&mut self) -> bool {
        if self.open.is_empty()
            && self.accepted.is_empty()
            && let Some(best) = self.incumbent.take()
        {
            // Nothing open can beat the incumbent: it is the optimum.
            self.accepted.push(best);
        }
        self.done()
    }

    /// The cost of the cheapest configuration found so far.
    pub(crate) fn best(&self) -> Option<u64> {
        match self.accepted.first() {
            Some((g, _)) => Some(*g),
            None => self.incumbent.as_ref().map(|(g, _)| *g),
        }
    }

    /// No configuration not yet accepted costs less than this.
    pub(crate) fn lower_bound(&self) -> Option<u64> {
        if !self.started {
            let h = self.h(&self.root_state());
            return (h != INFEASIBLE).then_some(h);
        }
        let open = self.open.peek().map(|(Reverse(f), _, _)| *f);
        match (open, self.incumbent.as_ref().map(|i| i.0)) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Builds the configurations: proven ones, then (budget exceeded) the
    /// incumbent. After the first, asks `over` before each whether the budget
    /// ran out; the last value says whether every one was built. When there
    /// is none, says why if `explain`.
    pub(crate) fn finish(
        &mut self,
        engine: &mut Engine<'_>,
        complete: bool,
        explain: bool,
        over: &dyn Fn() -> bool,
    ) -> (Vec<Configuration>, Option<explain::Explanation>, bool) {
        let mut out = Vec::new();
        let mut list: Vec<(u64, Vec<u32>, bool)> =
            self.accepted.drain(..).map(|(g, c)| (g, c, true)).collect();
        if list.is_empty()
            && let Some((g, c)) = self.incumbent.take()
        {
            list.push((g, c, complete));
        }
        let mut whole = true;
        for (g, choice, proven) in list {
            if !out.is_empty() && over() {
                whole = false;
                break;
            }
            let chooser = |consumer: Option<(ItemId, &GInfo)>| -> Option<u32> {
                let need = match consumer {
                    None => 0,
                    Some((item, info)) => {
                        let p = self
                            .provs
                            .get(*self.prov_of_item.get(item.0 as usize)? as usize)?;
                        let k = p.needs.iter().position(|(i, _)| i == info)?;
                        p.first_need as usize + k
                    }
                };
                let o = *choice.get(need)?;
                self.opts_of(need).get(o as usize).map(|o| o.alt)
            };
            match engine.assemble_with(&chooser) {
                Ok(mut config) => {
                    debug_assert_eq!(config.cost, g, "the search's cost is the configuration's");
                    config.optimal = proven;
                    out.push(config);
                }
                Err(reason) => engine.reject(reason),
            }
        }
        let explanation = (out.is_empty() && complete && explain)
            .then(|| explain::explain(&engine.ctx, &engine.graph, engine.root, &engine.rejections));
        (out, explanation, whole)
    }
}
