//! Best-first search with branch-and-bound over partial configurations.
//!
//! A node is a partial decomposition: the paper's stack of unexpanded task
//! instances plus the functionalities placed so far. Expanding a node pops the
//! top task instance and makes one child per alternative (method and binding).
//! Nodes store only their parent and the alternative taken; the partial
//! configuration is replayed from the root when a node is expanded, which keeps
//! nodes a few dozen bytes each.
//!
//! `f = g + h` where `g` charges each functionality occurrence its share (see
//! `ground`) and `h` sums the lower bounds of the pending instances; `f` never
//! exceeds the cost of any completion. A greedy dive first finds an incumbent
//! whose cost bounds the search (branch-and-bound); complete nodes are
//! assembled and checked for admissibility (channels, rates, sharing) when
//! popped, and re-queued at their true cost, so configurations come out
//! cheapest first.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::collections::hash_map::Entry;

use rustc_hash::{FxHashMap as HashMap, FxHashSet as HashSet};

use crate::compile::{CInfo, Callee, GInfo, Sym, Symbols};
use crate::ground::{Ctx, Graph, INFEASIBLE, ItemId, ItemKind};
use crate::model::{ChannelInstance, Configuration, FunctionalityInstance};
use ecology_domain::Name;

const NO_PARENT: u32 = u32::MAX;
/// Ground items a graph has room for before it grows: a small ecology's.
const GRAPH_CAPACITY: usize = 64;

/// A wire: the consumer's component, the information, the producer's and
/// the consumer's instance.
type Wire = (ComponentKey, GInfo, u32, u32);

/// A component: (PEIS, component).
type ComponentKey = (Sym, Sym);

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum NodeState {
    Open,
    /// Complete, but not yet checked for admissibility.
    Complete,
    /// Complete and admissible; its configuration is in `Engine::assembled`.
    Assembled(u32),
    /// Expanded or assembled by the dive; nothing more to do with it.
    Closed,
}

#[derive(Debug, Clone, Copy)]
struct Node {
    parent: u32,
    alt: u32,
    /// Shares of the functionalities placed so far.
    g: u64,
    /// Sum of the lower bounds of the pending task instances.
    h: u64,
    depth: u32,
    state: NodeState,
}

impl Node {
    fn f(&self) -> u64 {
        self.g.saturating_add(self.h)
    }
}

/// A task or functionality instance in a partial configuration.
#[derive(Debug, Clone)]
struct Inst {
    item: ItemId,
    /// The parent instance and this instance's subtask index in the parent's method.
    parent: Option<(u32, u16)>,
    alt: Option<u32>,
    /// Its children are the instances from here on, one per subtask of its
    /// alternative: they are added together.
    first_child: u32,
}

impl Inst {
    /// The instance of subtask `k`.
    fn child(&self, k: u16) -> u32 {
        self.first_child + k as u32
    }
}

/// A partial configuration, replayed from a node's path.
#[derive(Debug, Default)]
struct Partial {
    insts: Vec<Inst>,
    stack: Vec<u32>,
    /// The functionality instance each component runs, kept for the tree
    /// search's clash checks; `None` when only assembling (which checks
    /// components itself).
    used: Option<HashMap<ComponentKey, ItemId>>,
    /// The occurrence where each (task instance, alternative) that may
    /// share was first applied: a later one shares its subtree (see
    /// `Engine::apply`).
    applied: HashMap<(ItemId, u32), u32>,
}

impl Partial {
    /// A partial configuration holding only the goal's occurrence, `root`,
    /// that keeps track of the components in use when `tracked`.
    fn rooted(root: ItemId, tracked: bool) -> Partial {
        Partial {
            insts: vec![Inst {
                item: root,
                parent: None,
                alt: None,
                first_child: 0,
            }],
            stack: Vec::new(),
            used: tracked.then(HashMap::default),
            applied: HashMap::default(),
        }
    }
}

/// Names the alternative of a task occurrence from the functionality instance
/// and input it feeds (`None`: the goal).
pub(crate) type Chooser<'c> = dyn Fn(Option<(ItemId, &GInfo)>) -> Option<u32> + 'c;

/// Why a complete decomposition is not an admissible configuration.
pub(crate) type Inadmissible = String;

/// The search state machine.
pub(crate) struct Engine<'a> {
    pub(crate) ctx: Ctx<'a>,
    pub(crate) graph: Graph,
    pub(crate) root: ItemId,
    nodes: Vec<Node>,
    open: BinaryHeap<(Reverse<u64>, u32, Reverse<u32>)>,
    /// Upper bound from the incumbent (only when looking for one configuration).
    bound: u64,
    pub(crate) assembled: Vec<Configuration>,
    pub(crate) accepted: Vec<Configuration>,
    signatures: HashSet<String>,
    pub(crate) expanded: u64,
    pub(crate) generated: u64,
    /// Distinct reasons complete decompositions were rejected, with counts.
    pub(crate) rejections: Vec<(Inadmissible, u64)>,
    pub(crate) incumbent: Option<Configuration>,
    /// Whether repeated task occurrences may share subtrees (see
    /// `Engine::shares`): when looking for the cheapest configuration only,
    /// so that a list of several keeps every admissible one.
    share_repeats: bool,
}

impl<'a> Engine<'a> {
    /// Grounds the goal, asking `over` now and then whether the budget ran
    /// out (then `graph.cut` is set and the engine must not be searched;
    /// `cut` says it already has). `share_repeats`: looking for the cheapest
    /// configuration only (see `Engine::shares`).
    pub(crate) fn new(
        ctx: Ctx<'a>,
        goal: Callee,
        args: &[Sym],
        cut: bool,
        share_repeats: bool,
        over: &dyn Fn() -> bool,
    ) -> Engine<'a> {
        // Already cut (while reading the state): only the goal's item, empty.
        let mut graph = Graph::with_capacity(GRAPH_CAPACITY);
        graph.cut = cut;
        let root = graph.ground_until(&ctx, goal, args, over);
        let mut engine = Engine {
            ctx,
            graph,
            root,
            nodes: Vec::new(),
            open: BinaryHeap::new(),
            bound: INFEASIBLE,
            assembled: Vec::new(),
            accepted: Vec::new(),
            signatures: HashSet::default(),
            expanded: 0,
            generated: 0,
            rejections: Vec::new(),
            incumbent: None,
            share_repeats,
        };
        let lb = engine.graph.item(root).lb;
        if lb != INFEASIBLE && !engine.graph.cut {
            let (g, h, state) = match engine.graph.item(root).kind {
                ItemKind::Func(_) => (lb, 0, NodeState::Complete),
                ItemKind::Task { .. } => (0, lb, NodeState::Open),
            };
            engine.push(Node {
                parent: NO_PARENT,
                alt: 0,
                g,
                h,
                depth: 0,
                state,
            });
        }
        engine
    }

    fn push(&mut self, node: Node) -> u32 {
        let id = self.nodes.len() as u32;
        self.nodes.push(node);
        self.open.push((Reverse(node.f()), node.depth, Reverse(id)));
        self.generated += 1;
        id
    }

    /// The lowest `f` still open: a lower bound on anything not yet accepted.
    pub(crate) fn lower_bound(&self) -> Option<u64> {
        self.open.peek().map(|(Reverse(f), _, _)| *f)
    }

    /// Whether nothing is left to search.
    pub(crate) fn is_exhausted(&self) -> bool {
        self.open.is_empty()
    }

    /// Pops and processes one node; returns whether a configuration was accepted.
    pub(crate) fn step(&mut self, keep_bound: bool) -> bool {
        let Some((Reverse(f), _, Reverse(id))) = self.open.pop() else {
            return false;
        };
        if keep_bound && f >= self.bound {
            // Branch-and-bound: nothing below can beat the incumbent.
            self.open.clear();
            return false;
        }
        let node = self.nodes[id as usize];
        match node.state {
            NodeState::Open => {
                self.expanded += 1;
                let partial = self.replay(id);
                for child in self.children(id, &partial) {
                    if !keep_bound || child.f() < self.bound {
                        self.push(child);
                    }
                }
                false
            }
            NodeState::Complete => {
                let partial = self.replay(id);
                match self.assemble(&partial) {
                    Ok(config) if keep_bound && config.cost >= self.bound => {
                        // No better than the incumbent.
                        false
                    }
                    Ok(config) => {
                        let cost = config.cost;
                        let at = self.assembled.len() as u32;
                        self.assembled.push(config);
                        let mut done = node;
                        done.state = NodeState::Assembled(at);
                        // Re-queue at the true cost: channel costs and sharing
                        // can only raise it above the bound.
                        done.g = cost;
                        done.h = 0;
                        if self.lower_bound().is_none_or(|lb| cost <= lb) {
                            return self.accept(at);
                        }
                        self.nodes[id as usize] = done;
                        self.open.push((Reverse(cost), done.depth, Reverse(id)));
                        false
                    }
                    Err(reason) => {
                        self.reject(reason);
                        false
                    }
                }
            }
            NodeState::Assembled(at) => self.accept(at),
            NodeState::Closed => false,
        }
    }

    fn accept(&mut self, at: u32) -> bool {
        let config = self.assembled[at as usize].clone();
        if !self.signatures.insert(config.signature()) {
            return false;
        }
        self.accepted.push(config);
        true
    }

    pub(crate) fn reject(&mut self, reason: Inadmissible) {
        if let Some((_, n)) = self.rejections.iter_mut().find(|(r, _)| *r == reason) {
            *n += 1;
        } else if self.rejections.len() < 64 {
            self.rejections.push((reason, 1));
        }
    }

    /// A greedy depth-first dive from the best open node, to find an incumbent
    /// quickly; sets the bound. Gives up after `limit` expansions.
    pub(crate) fn dive(&mut self, limit: u64) {
        let Some(&(_, _, Reverse(start))) = self.open.peek() else {
            return;
        };
        let mut stack = vec![start];
        let mut spent = 0;
        while let Some(id) = stack.pop() {
            let node = self.nodes[id as usize];
            if node.f() >= self.bound {
                continue;
            }
            if node.state != NodeState::Closed {
                self.nodes[id as usize].state = NodeState::Closed;
            }
            match node.state {
                NodeState::Closed => {}
                NodeState::Open => {
                    if spent == limit {
                        // Leave it for the best-first search.
                        self.nodes[id as usize].state = NodeState::Open;
                        return;
                    }
                    spent += 1;
                    self.expanded += 1;
                    let partial = self.replay(id);
                    let mut children: Vec<Node> = self
                        .children(id, &partial)
                        .into_iter()
                        .filter(|c| c.f() < self.bound)
                        .collect();
                    // Best child last, so it is popped first.
                    children.sort_by_key(|c| (Reverse(c.f()), c.depth));
                    for child in children {
                        let cid = self.push(child);
                        stack.push(cid);
                    }
                }
                NodeState::Complete => {
                    let partial = self.replay(id);
                    match self.assemble(&partial) {
                        Ok(config) => {
                            self.bound = config.cost;
                            self.incumbent = Some(config);
                            return;
                        }
                        Err(reason) => self.reject(reason),
                    }
                }
                NodeState::Assembled(at) => {
                    let config = self.assembled[at as usize].clone();
                    self.bound = config.cost;
                    self.incumbent = Some(config);
                    return;
                }
            }
        }
    }

    /// Assembles the decomposition in which every task occurrence takes the
    /// alternative `choose` names for the functionality and input it feeds
    /// (`None`: the goal). A task occurrence whose task instance and
    /// alternative were assembled before shares that subtree rather than
    /// repeating it: a provider feeding two consumers is wired once, and
    /// providers shared level after level do not unfold into a tree that
    /// doubles with each level.
    pub(crate) fn assemble_with(
        &self,
        choose: &Chooser<'_>,
    ) -> Result<Configuration, Inadmissible> {
        let mut partial = Partial::rooted(self.root, false);
        partial.stack.push(0);
        while let Some(top) = partial.stack.pop() {
            let consumer =
                match partial.insts[top as usize].parent {
                    None => None,
                    Some((parent, k)) => {
                        let p = &partial.insts[parent as usize];
                        let ItemKind::Task { alts, .. } = &self.graph.item(p.item).kind else {
                            return Err("a functionality has subtasks".into());
                        };
                        let alt = &alts[p.alt.unwrap_or(0) as usize];
                        let method = &self.ctx.compiled.methods[alt.method as usize];
                        method.channels.iter().find(|(from, _, _)| *from == k).map(
                            |(_, to, info)| {
                                (
                                    partial.insts[p.child(*to) as usize].item,
                                    info.ground(&alt.binding),
                                )
                            },
                        )
                    }
                };
            let alt = choose(consumer.as_ref().map(|(item, info)| (*item, info)))
                .ok_or_else(|| "a task occurrence has no chosen alternative".to_string())?;
            // The provider search chose per input it feeds: one alternative
            // chosen twice is one provider serving two consumers.
            self.apply(&mut partial, top, alt, true);
        }
        self.assemble(&partial)
    }

    fn path(&self, mut id: u32) -> Vec<u32> {
        let mut alts = Vec::new();
        while self.nodes[id as usize].parent != NO_PARENT {
            alts.push(self.nodes[id as usize].alt);
            id = self.nodes[id as usize].parent;
        }
        alts.reverse();
        alts
    }

    fn replay(&self, id: u32) -> Partial {
        let mut partial = Partial::rooted(self.root, true);
        match self.graph.func(self.root) {
            Some(f) => {
                if let Some(used) = &mut partial.used {
                    used.insert((f.peis, f.component), self.root);
                }
            }
            None => partial.stack.push(0),
        }
        for alt in self.path(id) {
            let Some(top) = partial.stack.pop() else {
                break;
            };
            let share = self.shares(partial.insts[top as usize].item, alt);
            self.apply(&mut partial, top, alt, share);
        }
        partial
    }

    /// Whether a repeated occurrence of task instance `item` with alternative
    /// `alt` shares the subtree of its first occurrence in the tree search:
    /// only when looking for the cheapest configuration, and only when each
    /// output of the alternative comes from one of its own functionality
    /// instances. Then that instance feeds the consumers of both occurrences
    /// (a component runs one instance), each of its inputs has one producer,
    /// and so on down: a second subtree could only add instances that feed
    /// nothing else, at a cost. Sharing keeps the tree search from searching
    /// a shared provider's inputs again at each occurrence, which doubles
    /// with each level where providers are shared.
    fn shares(&self, item: ItemId, alt: u32) -> bool {
        if !self.share_repeats {
            return false;
        }
        let ItemKind::Task { alts, .. } = &self.graph.item(item).kind else {
            return false;
        };
        let alt = &alts[alt as usize];
        let method = &self.ctx.compiled.methods[alt.method as usize];
        method.outputs.iter().all(|(_, sub)| {
            alt.children
                .get(*sub as usize)
                .is_some_and(|&child| self.graph.func(child).is_some())
        })
    }

    /// Applies alternative `alt` to the task occurrence `top`: its subtasks
    /// join the partial configuration and its open tasks the stack. With
    /// `share`, an occurrence of a (task instance, alternative) applied
    /// before shares that subtree instead: its children are the first
    /// occurrence's, and nothing is left open.
    fn apply(&self, partial: &mut Partial, top: u32, alt: u32, share: bool) {
        let item = partial.insts[top as usize].item;
        let ItemKind::Task { alts, .. } = &self.graph.item(item).kind else {
            return;
        };
        // Whether an occurrence shares depends on its (task instance,
        // alternative) alone: only those that share are kept track of.
        if share {
            match partial.applied.entry((item, alt)) {
                Entry::Occupied(first) => {
                    let first_child = partial.insts[*first.get() as usize].first_child;
                    let inst = &mut partial.insts[top as usize];
                    (inst.alt, inst.first_child) = (Some(alt), first_child);
                    return;
                }
                Entry::Vacant(slot) => {
                    slot.insert(top);
                }
            }
        }
        let alt_data = &alts[alt as usize];
        let first = partial.insts.len() as u32;
        partial.insts[top as usize].alt = Some(alt);
        partial.insts[top as usize].first_child = first;
        for (k, &child) in alt_data.children.iter().enumerate() {
            partial.insts.push(Inst {
                item: child,
                parent: Some((top, k as u16)),
                alt: None,
                first_child: 0,
            });
            if let Some(f) = self.graph.func(child)
                && let Some(used) = &mut partial.used
            {
                used.entry((f.peis, f.component)).or_insert(child);
            }
        }
        // The subtasks, the first ending on top of the stack.
        let graph = &self.graph;
        partial.stack.extend(
            (first..first + alt_data.children.len() as u32)
                .rev()
                .filter(|&at| {
                    graph
                        .func(alt_data.children[(at - first) as usize])
                        .is_none()
                }),
        );
    }

    fn children(&mut self, id: u32, partial: &Partial) -> Vec<Node> {
        let node = self.nodes[id as usize];
        let Some(&top) = partial.stack.last() else {
            return Vec::new();
        };
        let item = self.graph.item(partial.insts[top as usize].item);
        let ItemKind::Task { alts, .. } = &item.kind else {
            return Vec::new();
        };
        let pending = partial.stack.len() - 1;
        let mut out = Vec::new();
        let mut clashes = Vec::new();
        let item_id = partial.insts[top as usize].item;
        'alts: for (a, alt) in alts.iter().enumerate() {
            if alt.lb == INFEASIBLE {
                continue;
            }
            if self.shares(item_id, a as u32) && partial.applied.contains_key(&(item_id, a as u32))
            {
                // Shares a subtree already counted: nothing new to pay or open.
                out.push(Node {
                    parent: id,
                    alt: a as u32,
                    g: node.g,
                    h: node.h - item.lb,
                    depth: node.depth + 1,
                    state: if pending == 0 {
                        NodeState::Complete
                    } else {
                        NodeState::Open
                    },
                });
                continue;
            }
            let mut g = node.g;
            let mut h = node.h - item.lb;
            let mut tasks = 0;
            for &child in alt.children.iter() {
                match self.graph.func(child) {
                    Some(f) => {
                        if let Some(&other) = partial
                            .used
                            .as_ref()
                            .and_then(|used| used.get(&(f.peis, f.component)))
                            && other != child
                        {
                            // The component already runs another functionality.
                            clashes.push((other, child, f.peis, f.component));
                            continue 'alts;
                        }
                        g += f.share;
                    }
                    None => {
                        h += self.graph.item(child).lb;
                        tasks += 1;
                    }
                }
            }
            out.push(Node {
                parent: id,
                alt: a as u32,
                g,
                h,
                depth: node.depth + 1,
                state: if pending + tasks == 0 {
                    NodeState::Complete
                } else {
                    NodeState::Open
                },
            });
        }
        for (a, b, peis, component) in clashes {
            let syms = &self.ctx.compiled.syms;
            let reason = format!(
                "component {}:{} would run both {} and {}",
                syms.name(peis),
                syms.name(component),
                self.describe(a),
                self.describe(b)
            );
            self.reject(reason);
        }
        out
    }

    fn describe(&self, item: ItemId) -> String {
        crate::explain::describe(&self.ctx, &self.graph, item)
    }

    /// The ground arguments of an item, which bind its schema's slots in order.
    fn args_of(&self, item: ItemId) -> &[Sym] {
        &self.graph.item(item).args
    }
    fn info_text(&self, info: &GInfo) -> String {
        info.text(&self.ctx.compiled.syms)
    }

    /// The label path of an instance, like `f0/f1/f2`.
    fn label(&self, partial: &Partial, inst: u32) -> String {
        let mut text = String::new();
        self.label_into(partial, inst, &mut Vec::new(), &mut text);
        text
    }

    /// Writes the label path of an instance into `text`, using `parts`.
    fn label_into(
        &self,
        partial: &Partial,
        mut inst: u32,
        parts: &mut Vec<&'a str>,
        text: &mut String,
    ) {
        parts.clear();
        text.clear();
        while let Some((parent, k)) = partial.insts[inst as usize].parent {
            let p = &partial.insts[parent as usize];
            let label = p
                .alt
                .and_then(|alt| match &self.graph.item(p.item).kind {
                    ItemKind::Task { alts, .. } => Some(alts[alt as usize].method),
                    ItemKind::Func(_) => None,
                })
                .map(|m| self.ctx.subtask_label(m, k))
                .unwrap_or("?");
            parts.push(label);
            inst = parent;
        }
        if parts.is_empty() {
            text.push_str("goal");
        }
        for (i, part) in parts.iter().rev().enumerate() {
            if i > 0 {
                text.push('/');
            }
            text.push_str(part);
        }
    }

    /// The functionality instance providing `info` out of instance `inst`.
    fn producer(
        &self,
        partial: &Partial,
        mut inst: u32,
        info: &GInfo,
    ) -> Result<u32, Inadmissible> {
        loop {
            let i = &partial.insts[inst as usize];
            let ItemKind::Task { alts, .. } = &self.graph.item(i.item).kind else {
                return Ok(inst);
            };
            let alt = &alts[i.alt.unwrap_or(0) as usize];
            let method = &self.ctx.compiled.methods[alt.method as usize];
            let found = method
                .outputs
                .iter()
                .find(|(out, _)| out.grounds_to(&alt.binding, info));
            match found {
                Some((_, sub)) => inst = i.child(*sub),
                None => {
                    return Err(format!(
                        "{} ({}) does not provide {} with method {}",
                        self.label(partial, inst),
                        self.describe(i.item),
                        self.info_text(info),
                        self.ctx.method_name(alt.method)
                    ));
                }
            }
        }
    }

    /// Every functionality instance consuming `info` delivered to instance `inst`.
    fn consumers(
        &self,
        partial: &Partial,
        inst: u32,
        info: &GInfo,
        out: &mut Vec<u32>,
    ) -> Result<(), Inadmissible> {
        let i = &partial.insts[inst as usize];
        let ItemKind::Task { alts, .. } = &self.graph.item(i.item).kind else {
            out.push(inst);
            return Ok(());
        };
        let alt = &alts[i.alt.unwrap_or(0) as usize];
        let method = &self.ctx.compiled.methods[alt.method as usize];
        let mut any = false;
        for (input, sub) in &method.inputs {
            if input.grounds_to(&alt.binding, info) {
                any = true;
                self.consumers(partial, i.child(*sub), info, out)?;
            }
        }
        if any {
            Ok(())
        } else {
            Err(format!(
                "{} ({}) does not take {} as input with method {}",
                self.label(partial, inst),
                self.describe(i.item),
                self.info_text(info),
                self.ctx.method_name(alt.method)
            ))
        }
    }

    /// Turns a complete decomposition into a configuration, or says why it is
    /// not admissible.
    fn assemble(&self, partial: &Partial) -> Result<Configuration, Inadmissible> {
        let (by_component, order) = self.instances_by_component(partial)?;
        let wires = self.wires(partial)?;
        self.check_wires(partial, &wires)?;
        self.check_inputs_connected(partial, &order, &wires)?;
        // Labels and information texts, built once: channels name them again.
        let mut labels: Vec<Option<Name>> = vec![None; partial.insts.len()];
        let (mut parts, mut text) = (Vec::new(), String::new());
        for &at in &order {
            self.label_into(partial, at, &mut parts, &mut text);
            labels[at as usize] = Some(Name::from(text.as_str()));
        }
        let mut texts = InfoTexts::default();
        // Cost: distinct components, plus distinct channels between PEIS.
        let (functionalities, components_cost) =
            self.functionality_instances(partial, &order, &labels, &mut texts);
        let (channels, channels_cost) =
            self.channel_instances(partial, &wires, &by_component, &labels, &mut texts);
        Ok(Configuration {
            cost: components_cost.saturating_add(channels_cost),
            optimal: false,
            functionalities,
            channels,
        })
    }

    /// The component running the functionality instance at `inst`, if it is one.
    fn component_at(&self, partial: &Partial, inst: u32) -> Option<ComponentKey> {
        let f = self.graph.func(partial.insts[inst as usize].item);
        f.map(|f| (f.peis, f.component))
    }

    /// Functionality instances, one per component: the first instance on
    /// each component, and those components in order of first use.
    fn instances_by_component(
        &self,
        partial: &Partial,
    ) -> Result<(HashMap<ComponentKey, u32>, Vec<u32>), Inadmissible> {
        let c = &self.ctx.compiled;
        let mut by_component: HashMap<ComponentKey, u32> =
            HashMap::with_capacity_and_hasher(partial.insts.len(), Default::default());
        let mut order: Vec<u32> = Vec::with_capacity(partial.insts.len());
        for (at, inst) in partial.insts.iter().enumerate() {
            let Some(f) = self.graph.func(inst.item) else {
                continue;
            };
            match by_component.get(&(f.peis, f.component)) {
                Some(&first) if partial.insts[first as usize].item != inst.item => {
                    return Err(format!(
                        "component {}:{} would run both {} and {}",
                        c.syms.name(f.peis),
                        c.syms.name(f.component),
                        self.describe(partial.insts[first as usize].item),
                        self.describe(inst.item)
                    ));
                }
                Some(_) => {}
                None => {
                    by_component.insert((f.peis, f.component), at as u32);
                    order.push(at as u32);
                }
            }
        }
        Ok((by_component, order))
    }

    /// Wires: (consumer component, info) → producer instance, resolved
    /// through the methods' channels; one producer per consumer input.
    fn wires(&self, partial: &Partial) -> Result<Vec<Wire>, Inadmissible> {
        let c = &self.ctx.compiled;
        let key = |inst: u32| self.component_at(partial, inst);
        let mut wires: Vec<Wire> = Vec::new();
        for inst in &partial.insts {
            let ItemKind::Task { alts, .. } = &self.graph.item(inst.item).kind else {
                continue;
            };
            let Some(alt) = inst.alt.map(|a| &alts[a as usize]) else {
                continue;
            };
            let method = &c.methods[alt.method as usize];
            for (from, to, info) in &method.channels {
                let info = info.ground(&alt.binding);
                let producer = self.producer(partial, inst.child(*from), &info)?;
                let mut consumers = Vec::new();
                self.consumers(partial, inst.child(*to), &info, &mut consumers)?;
                for consumer in consumers {
                    let (Some(_), Some(ckey)) = (key(producer), key(consumer)) else {
                        continue;
                    };
                    let existing = wires.iter().find(|(k, i, _, _)| *k == ckey && *i == info);
                    match existing {
                        Some(&(_, _, p, _)) if key(p) != key(producer) => {
                            return Err(format!(
                                "input {} of {} would come from both {} and {}",
                                self.info_text(&info),
                                self.describe(partial.insts[consumer as usize].item),
                                self.describe(partial.insts[p as usize].item),
                                self.describe(partial.insts[producer as usize].item),
                            ));
                        }
                        Some(_) => {}
                        None => wires.push((ckey, info.clone(), producer, consumer)),
                    }
                }
            }
        }
        Ok(wires)
    }

    /// Every wire carries an output of its producer to an input of its
    /// consumer, at a sufficient rate.
    fn check_wires(&self, partial: &Partial, wires: &[Wire]) -> Result<(), Inadmissible> {
        let c = &self.ctx.compiled;
        for (_, info, producer, consumer) in wires {
            let pf = self.graph.func(partial.insts[*producer as usize].item);
            let cf = self.graph.func(partial.insts[*consumer as usize].item);
            let (Some(pf), Some(cf)) = (pf, cf) else {
                continue;
            };
            let pi = partial.insts[*producer as usize].item;
            let ci = partial.insts[*consumer as usize].item;
            let (p_args, c_args) = (self.args_of(pi), self.args_of(ci));
            let out = c.funcs[pf.func as usize]
                .outputs
                .iter()
                .find(|o| o.grounds_args_to(p_args, info));
            let input = c.funcs[cf.func as usize]
                .inputs
                .iter()
                .find(|i| i.grounds_args_to(c_args, info));
            let Some(out) = out else {
                return Err(format!(
                    "{} does not output {}",
                    self.describe(pi),
                    self.info_text(info)
                ));
            };
            let Some(input) = input else {
                return Err(format!(
                    "{} does not input {}",
                    self.describe(ci),
                    self.info_text(info)
                ));
            };
            if let Some(need) = input.hz
                && out.hz.is_none_or(|offered| offered < need)
            {
                let offered = out
                    .hz
                    .map_or("no stated rate".to_string(), |hz| format!("{hz} Hz"));
                return Err(format!(
                    "{} needs {} at {need} Hz but {} offers {offered}",
                    self.describe(ci),
                    self.info_text(info),
                    self.describe(pi)
                ));
            }
        }
        Ok(())
    }

    /// Every input of every functionality is connected.
    fn check_inputs_connected(
        &self,
        partial: &Partial,
        order: &[u32],
        wires: &[Wire],
    ) -> Result<(), Inadmissible> {
        let c = &self.ctx.compiled;
        for &at in order {
            let item = partial.insts[at as usize].item;
            let Some(f) = self.graph.func(item) else {
                continue;
            };
            let args = self.args_of(item);
            for input in &c.funcs[f.func as usize].inputs {
                if !wires.iter().any(|(k, i, _, _)| {
                    *k == (f.peis, f.component) && input.grounds_args_to(args, i)
                }) {
                    let info = input.ground_args(args);
                    return Err(format!(
                        "input {} of {} ({}) is not connected",
                        self.info_text(&info),
                        self.label(partial, at),
                        self.describe(item)
                    ));
                }
            }
        }
        Ok(())
    }

    /// The functionality instances of the components in `order`, and what
    /// the components cost together.
    fn functionality_instances(
        &self,
        partial: &Partial,
        order: &[u32],
        labels: &[Option<Name>],
        texts: &mut InfoTexts,
    ) -> (Vec<FunctionalityInstance>, u64) {
        let c = &self.ctx.compiled;
        let mut cost: u64 = 0;
        let mut functionalities = Vec::with_capacity(order.len());
        for &at in order {
            let item = partial.insts[at as usize].item;
            let Some(f) = self.graph.func(item) else {
                continue;
            };
            cost = cost.saturating_add(f.cost);
            let schema = &c.funcs[f.func as usize];
            let args = self.args_of(item);
            functionalities.push(FunctionalityInstance {
                label: labels[at as usize]
                    .clone()
                    .unwrap_or_else(|| Name::from("")),
                name: self.ctx.callee_name(Callee::Func(f.func)).clone(),
                args: args.iter().map(|&a| c.syms.shared(a).clone()).collect(),
                peis: c.syms.shared(f.peis).clone(),
                component: c.syms.shared(f.component).clone(),
                power: f.power,
                cost: f.cost,
                inputs: schema
                    .inputs
                    .iter()
                    .map(|i| texts.of_schema(i, args, &c.syms))
                    .collect(),
                outputs: schema
                    .outputs
                    .iter()
                    .map(|o| texts.of_schema(o, args, &c.syms))
                    .collect(),
                postcondition: self.ctx.ground_postcondition(f.func, args),
            });
        }
        (functionalities, cost)
    }

    /// The distinct channels of `wires` (producer, consumer, information),
    /// and what those between PEIS cost together.
    fn channel_instances(
        &self,
        partial: &Partial,
        wires: &[Wire],
        by_component: &HashMap<ComponentKey, u32>,
        labels: &[Option<Name>],
        texts: &mut InfoTexts,
    ) -> (Vec<ChannelInstance>, u64) {
        let c = &self.ctx.compiled;
        let label_of = |k: ComponentKey| {
            by_component
                .get(&k)
                .and_then(|&at| labels.get(at as usize)?.clone())
                .unwrap_or_else(|| Name::from(""))
        };
        let mut cost: u64 = 0;
        let mut channels = Vec::with_capacity(wires.len());
        let mut seen: HashSet<(ComponentKey, ComponentKey, GInfo)> =
            HashSet::with_capacity_and_hasher(wires.len(), Default::default());
        for (ckey, info, producer, _) in wires {
            let Some(pkey) = self.component_at(partial, *producer) else {
                continue;
            };
            if !seen.insert((pkey, *ckey, info.clone())) {
                continue;
            }
            let remote = pkey.0 != ckey.0;
            let channel_cost = if remote {
                self.ctx.channel_cost(pkey.0, ckey.0)
            } else {
                0
            };
            cost = cost.saturating_add(channel_cost);
            channels.push(ChannelInstance {
                from: label_of(pkey),
                to: label_of(*ckey),
                info: texts.of(info, &c.syms),
                info_name: c.syms.shared(info.name).clone(),
                from_peis: c.syms.shared(pkey.0).clone(),
                from_component: c.syms.shared(pkey.1).clone(),
                to_peis: c.syms.shared(ckey.0).clone(),
                to_component: c.syms.shared(ckey.1).clone(),
                remote,
                cost: channel_cost,
            });
        }
        (channels, cost)
    }
}

/// The texts of a configuration's information types, like `(image hsm)`,
/// each built once: a producer's output, its consumer's input and their
/// channel share one.
#[derive(Default)]
struct InfoTexts(Vec<(GInfo, Name)>);

impl InfoTexts {
    fn of(&mut self, info: &GInfo, syms: &Symbols) -> Name {
        match self.0.iter().find(|(i, _)| i == info) {
            Some((_, text)) => text.clone(),
            None => self.add(info.clone(), syms),
        }
    }

    /// The text of a schema's information grounded by an instance's arguments.
    fn of_schema(&mut self, info: &CInfo, args: &[Sym], syms: &Symbols) -> Name {
        match self.0.iter().find(|(i, _)| info.grounds_args_to(args, i)) {
            Some((_, text)) => text.clone(),
            None => self.add(info.ground_args(args), syms),
        }
    }

    /// Builds the text of `info`, not yet known, and keeps it.
    fn add(&mut self, info: GInfo, syms: &Symbols) -> Name {
        let text = Name::from(info.text(syms));
        self.0.push((info, text.clone()));
        text
    }
}
