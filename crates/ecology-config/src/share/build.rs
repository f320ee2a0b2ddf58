//! Building the provider search from the ground graph, in phases: recognise
//! provider shape and collect the providers, price the channels, list the
//! needs and their options, drop the providers that cannot be fed, then lay
//! out what the bound reads (cheapest first, the tasks each provider serves,
//! landmarks, conflicts).

use std::cell::RefCell;
use std::collections::BinaryHeap;

use rustc_hash::FxHashMap as HashMap;

use super::{Cut, NONE, Need, Opt, Prov, Shared, Task};
use crate::compile::{GInfo, Sym};
use crate::ground::{Alt, Ctx, Graph, INFEASIBLE, ItemId, ItemKind};
use crate::search::Engine;

impl Shared {
    /// The provider-shape search for `engine`'s goal, or `Ok(None)` when the
    /// domain does not have provider shape (or its providers could feed each
    /// other in a cycle). Asks `over` now and then whether the budget ran
    /// out; if so, returns [`Cut`].
    pub(crate) fn new(
        engine: &Engine<'_>,
        count: usize,
        over: &dyn Fn() -> bool,
    ) -> Result<Option<Shared>, Cut> {
        let Some(Layout {
            task_of_item,
            mut tasks,
            mut provs,
            prov_of_item,
            peis_syms,
            provided,
        }) = Layout::collect(engine)
        else {
            return Ok(None);
        };
        let npeis = peis_syms.len();
        let chan = channel_costs(&engine.ctx, &peis_syms, over)?;
        let mut needs = needs(&mut provs, &task_of_item);
        let feeds = Feeds {
            engine,
            tasks: &tasks,
            provs: &provs,
            provided: &provided,
            chan: &chan,
            npeis,
        };
        let mut opts = feeds.options(&mut needs, over)?;
        let dead = drop_unfed(&provs, &mut needs, &mut opts);
        // Providers that could feed each other in a cycle: not a tree
        // configuration, so leave the domain to the tree search.
        if has_cycle(&provs, &needs, &opts) {
            return Ok(None);
        }
        weigh(&mut provs, &mut tasks, &mut needs, &mut opts, &dead);
        let serves = serves(&mut provs, &tasks);
        let additive = provs.iter().all(|p| p.serves.1 - p.serves.0 <= 1);
        common_needs(&mut tasks, &provs, &task_of_item);
        conflicts(&engine.graph, &mut provs);
        let pwords = provs.len().div_ceil(64);
        let words = pwords + needs.len().div_ceil(64);
        Ok(Some(Shared {
            provs,
            serves,
            needs,
            opts,
            tasks,
            prov_of_item,
            chan,
            npeis,
            additive,
            pwords,
            words,
            count: count.max(1),
            nodes: Vec::new(),
            states: Vec::new(),
            open: BinaryHeap::new(),
            seen: HashMap::default(),
            bound: INFEASIBLE,
            incumbent: None,
            accepted: Vec::new(),
            started: false,
            scratch: RefCell::default(),
            expanded: 0,
            generated: 0,
        }))
    }
}

/// What recognising provider shape finds on the ground graph.
struct Layout {
    /// By item index: the task of the search (`NONE`: not one).
    task_of_item: Vec<u32>,
    /// The tasks, the goal's first, then in the order providers need them.
    tasks: Vec<Task>,
    provs: Vec<Prov>,
    /// By item index: the provider (`NONE`: not one).
    prov_of_item: Vec<u32>,
    /// The providers' PEIS, numbered as `Prov::peis` numbers them.
    peis_syms: Vec<Sym>,
    /// What each alternative's provider provides, back to back.
    provided: Vec<GInfo>,
}

/// One alternative's wiring, in buffers reused for every alternative.
#[derive(Default)]
struct Wiring {
    /// By child: whether a channel leaves it.
    fed: Vec<bool>,
    /// The functionality's inputs, ground.
    inputs: Vec<GInfo>,
    /// By input: the task child feeding it.
    fed_by: Vec<Option<ItemId>>,
}

impl Layout {
    /// Recognises provider shape: walks the tasks from the goal down, and
    /// makes the one functionality of each feasible alternative a provider
    /// (once per functionality instance), its inputs needs on the tasks that
    /// feed them. `None` when an alternative breaks the shape.
    fn collect(engine: &Engine<'_>) -> Option<Layout> {
        let graph = &engine.graph;
        let c = &engine.ctx.compiled;
        if !matches!(graph.item(engine.root).kind, ItemKind::Task { .. }) {
            return None;
        }
        let mut layout = Layout {
            task_of_item: vec![NONE; graph.items.len()],
            tasks: Vec::new(),
            provs: Vec::new(),
            prov_of_item: vec![NONE; graph.items.len()],
            peis_syms: Vec::new(),
            provided: Vec::new(),
        };
        let mut peis_index: HashMap<Sym, u32> = HashMap::default();
        layout.task_of_item[engine.root.0 as usize] = 0;
        layout.tasks.push(Task {
            item: engine.root,
            ..Task::default()
        });
        let mut wiring = Wiring::default();
        let mut next = 0;
        while next < layout.tasks.len() {
            let item = graph.item(layout.tasks[next].item);
            let ItemKind::Task { alts, .. } = &item.kind else {
                return None;
            };
            for (a, alt) in alts.iter().enumerate() {
                if alt.lb == INFEASIBLE {
                    continue;
                }
                let sf = wiring.read(engine, alt)?;
                let first_provided = layout.provided.len() as u32;
                layout.provided.extend(
                    c.methods[alt.method as usize]
                        .outputs
                        .iter()
                        .filter(|(_, sub)| *sub as usize == sf)
                        .map(|(o, _)| o.ground(&alt.binding)),
                );
                let p = layout.provider(graph, alt.children[sf], &mut wiring, &mut peis_index)?;
                let last_provided = layout.provided.len() as u32;
                layout.tasks[next]
                    .alts
                    .push((a as u32, p, first_provided, last_provided));
            }
            next += 1;
        }
        Some(layout)
    }

    /// The provider running functionality item `f_item`, wired as `wiring`
    /// says: made the first time (its needs' tasks added to the walk), found
    /// again later, when it must be wired the same. `None` when it is not.
    fn provider(
        &mut self,
        graph: &Graph,
        f_item: ItemId,
        wiring: &mut Wiring,
        peis_index: &mut HashMap<Sym, u32>,
    ) -> Option<u32> {
        let f = graph.func(f_item)?;
        let p = self.prov_of_item[f_item.0 as usize];
        if p != NONE {
            // One provider, one wiring of its inputs: the tree search's
            // shared subtrees must agree, and so must these.
            let needs = &self.provs[p as usize].needs;
            let same = needs.len() == wiring.inputs.len()
                && needs
                    .iter()
                    .zip(wiring.inputs.iter().zip(&wiring.fed_by))
                    .all(|((i, t), (j, u))| i == j && Some(*t) == *u);
            return same.then_some(p);
        }
        let peis = *peis_index.entry(f.peis).or_insert_with(|| {
            self.peis_syms.push(f.peis);
            self.peis_syms.len() as u32 - 1
        });
        let needs: Vec<(GInfo, ItemId)> = wiring
            .inputs
            .drain(..)
            .zip(&wiring.fed_by)
            .filter_map(|(i, t)| t.map(|t| (i, t)))
            .collect();
        for (_, t) in &needs {
            if self.task_of_item[t.0 as usize] == NONE {
                self.task_of_item[t.0 as usize] = self.tasks.len() as u32;
                self.tasks.push(Task {
                    item: *t,
                    ..Task::default()
                });
            }
        }
        self.provs.push(Prov {
            item: f_item,
            peis,
            cost: f.cost,
            first_need: 0,
            needs,
            conflicts: Vec::new(),
            w: 0,
            serves: (0, 0),
        });
        let p = self.provs.len() as u32 - 1;
        self.prov_of_item[f_item.0 as usize] = p;
        Some(p)
    }
}

impl Wiring {
    /// Reads alternative `alt`'s wiring: it must run one functionality, and
    /// each other child must be a task feeding one distinct input of it by a
    /// channel, every input fed. Returns the functionality's child, with the
    /// inputs and their feeders in `self`; `None` when the shape is broken.
    fn read(&mut self, engine: &Engine<'_>, alt: &Alt) -> Option<usize> {
        let graph = &engine.graph;
        let c = &engine.ctx.compiled;
        let mut funcs = (0..alt.children.len()).filter(|&k| graph.func(alt.children[k]).is_some());
        let (Some(sf), None) = (funcs.next(), funcs.next()) else {
            return None;
        };
        let f_item = alt.children[sf];
        let f = graph.func(f_item)?;
        let method = &c.methods[alt.method as usize];
        let f_args = &graph.item(f_item).args;
        self.inputs.clear();
        self.inputs.extend(
            c.funcs[f.func as usize]
                .inputs
                .iter()
                .map(|i| i.ground_args(f_args)),
        );
        self.fed_by.clear();
        self.fed_by.resize(self.inputs.len(), None);
        self.fed.clear();
        self.fed.resize(alt.children.len(), false);
        for (from, to, info) in &method.channels {
            let (from, to) = (*from as usize, *to as usize);
            if to != sf || from == sf || self.fed[from] {
                return None;
            }
            self.fed[from] = true;
            let info = info.ground(&alt.binding);
            let k = self.inputs.iter().position(|i| *i == info)?;
            if self.fed_by[k].is_some() {
                return None;
            }
            self.fed_by[k] = Some(alt.children[from]);
        }
        let unfed = (0..alt.children.len()).any(|k| k != sf && !self.fed[k]);
        if unfed || self.fed_by.contains(&None) {
            return None;
        }
        Some(sf)
    }
}

/// Channel costs between every two PEIS, from the state and the cost model;
/// row: producer. Asks `over` every 64 rows.
fn channel_costs(
    ctx: &Ctx<'_>,
    peis_syms: &[Sym],
    over: &dyn Fn() -> bool,
) -> Result<Vec<u64>, Cut> {
    let c = &ctx.compiled;
    let npeis = peis_syms.len();
    let mut chan = vec![0u64; npeis * npeis];
    for (i, &a) in peis_syms.iter().enumerate() {
        // A row is `npeis` calls of the cost model.
        if i % 64 == 63 && over() {
            return Err(Cut);
        }
        for (j, &b) in peis_syms.iter().enumerate() {
            if i != j {
                chan[i * npeis + j] = ctx.cost_model.channel_cost(
                    c.syms.name(a),
                    c.syms.name(b),
                    ctx.channels.get(&(a, b)).copied(),
                );
            }
        }
    }
    Ok(chan)
}

/// The needs: the goal's, then each provider's inputs (setting its
/// `first_need`); their options are left to [`Feeds::options`].
fn needs(provs: &mut [Prov], task_of_item: &[u32]) -> Vec<Need> {
    let mut needs = vec![Need {
        consumer: NONE,
        task: 0,
        opts: (0, 0),
        min_wire: 0,
    }];
    for (p, prov) in provs.iter_mut().enumerate() {
        prov.first_need = needs.len() as u32;
        for (_, t) in &prov.needs {
            needs.push(Need {
                consumer: p as u32,
                task: task_of_item[t.0 as usize],
                opts: (0, 0),
                min_wire: 0,
            });
        }
    }
    needs
}

/// What listing the needs' options reads.
struct Feeds<'e, 'a> {
    engine: &'e Engine<'a>,
    tasks: &'e [Task],
    provs: &'e [Prov],
    provided: &'e [GInfo],
    chan: &'e [u64],
    npeis: usize,
}

impl Feeds<'_, '_> {
    /// Each need's options, by need, back to back (setting its `opts`): one
    /// per provider of its task that provides the information at a
    /// sufficient rate, with the channel's cost. Asks `over` every 256 needs.
    fn options(&self, needs: &mut [Need], over: &dyn Fn() -> bool) -> Result<Vec<Opt>, Cut> {
        let provs = self.provs;
        let mut opts: Vec<Opt> = Vec::with_capacity(needs.len() * 2);
        for (n, need) in needs.iter_mut().enumerate() {
            if n % 256 == 255 && over() {
                return Err(Cut);
            }
            let task = &self.tasks[need.task as usize];
            let consumer = need.consumer;
            let first = opts.len();
            for &(alt, g, from, to) in &task.alts {
                let provides = &self.provided[from as usize..to as usize];
                if opts[first..].iter().any(|o| o.prov == g) {
                    continue;
                }
                let wire = if consumer == NONE {
                    0
                } else {
                    let cons = &provs[consumer as usize];
                    let k = (n as u32 - cons.first_need) as usize;
                    let info = &cons.needs[k].0;
                    if !provides.contains(info)
                        || !rate_ok(self.engine, cons.item, k, provs[g as usize].item, info)
                    {
                        continue;
                    }
                    let (a, b) = (provs[g as usize].peis as usize, cons.peis as usize);
                    if a == b {
                        0
                    } else {
                        self.chan[a * self.npeis + b]
                    }
                };
                opts.push(Opt { alt, prov: g, wire });
            }
            need.opts = (first as u32, opts.len() as u32);
        }
        Ok(opts)
    }
}

/// Drops providers with an input nothing can feed, until none is left (a
/// dropped provider is no option of any need). Returns which were dropped.
fn drop_unfed(provs: &[Prov], needs: &mut [Need], opts: &mut [Opt]) -> Vec<bool> {
    let mut dead = vec![false; provs.len()];
    loop {
        let mut changed = false;
        for (p, prov) in provs.iter().enumerate() {
            if dead[p] {
                continue;
            }
            let first = prov.first_need as usize;
            if (first..first + prov.needs.len()).any(|n| needs[n].opts.0 == needs[n].opts.1) {
                dead[p] = true;
                changed = true;
            }
        }
        for need in needs.iter_mut() {
            let (from, to) = need.opts;
            let mut kept = from;
            for o in from..to {
                if !dead[opts[o as usize].prov as usize] {
                    opts[kept as usize] = opts[o as usize];
                    kept += 1;
                }
            }
            need.opts.1 = kept;
        }
        if !changed {
            return dead;
        }
    }
}

/// The bound's weights, cheapest first: each need's options by channel cost
/// (and its cheapest channel), each provider's `w` (its cost and its inputs'
/// cheapest channels; infinite when dropped), each task's providers by `w`
/// (and the least).
fn weigh(
    provs: &mut [Prov],
    tasks: &mut [Task],
    needs: &mut [Need],
    opts: &mut [Opt],
    dead: &[bool],
) {
    for need in needs.iter_mut() {
        let mine = &mut opts[need.opts.0 as usize..need.opts.1 as usize];
        mine.sort_by_key(|o| o.wire);
        need.min_wire = mine.first().map_or(INFEASIBLE, |o| o.wire);
    }
    for p in 0..provs.len() {
        let first = provs[p].first_need as usize;
        let w = (first..first + provs[p].needs.len())
            .map(|n| needs[n].min_wire)
            .fold(provs[p].cost, u64::saturating_add);
        provs[p].w = if dead[p] { INFEASIBLE } else { w };
    }
    for task in tasks.iter_mut() {
        let mut ps: Vec<u32> = task
            .alts
            .iter()
            .map(|a| a.1)
            .filter(|&p| !dead[p as usize])
            .collect();
        ps.sort_unstable();
        ps.dedup();
        ps.sort_by_key(|&p| provs[p as usize].w);
        task.wmin = ps
            .iter()
            .map(|&p| provs[p as usize].w)
            .min()
            .unwrap_or(INFEASIBLE);
        task.provs = ps;
    }
}

/// The tasks each provider serves, by provider, back to back (setting its
/// `serves` range).
fn serves(provs: &mut [Prov], tasks: &[Task]) -> Vec<u32> {
    let mut serves_from = vec![0u32; provs.len() + 1];
    for task in tasks {
        for &p in &task.provs {
            serves_from[p as usize + 1] += 1;
        }
    }
    for p in 0..provs.len() {
        serves_from[p + 1] += serves_from[p];
    }
    let mut serves = vec![0u32; serves_from[provs.len()] as usize];
    let mut fill = serves_from.clone();
    for (t, task) in tasks.iter().enumerate() {
        for &p in &task.provs {
            serves[fill[p as usize] as usize] = t as u32;
            fill[p as usize] += 1;
        }
    }
    for (p, prov) in provs.iter_mut().enumerate() {
        prov.serves = (serves_from[p], serves_from[p + 1]);
    }
    serves
}

/// Each task's `common`: the tasks every one of its providers needs, so that
/// a landmark task makes them landmarks too.
fn common_needs(tasks: &mut [Task], provs: &[Prov], task_of_item: &[u32]) {
    let (mut mine, mut common): (Vec<u32>, Vec<u32>) = Default::default();
    for task in tasks.iter_mut() {
        common.clear();
        for (k, &p) in task.provs.iter().enumerate() {
            mine.clear();
            mine.extend(
                provs[p as usize]
                    .needs
                    .iter()
                    .map(|(_, t)| task_of_item[t.0 as usize]),
            );
            if k == 0 {
                mine.sort_unstable();
                common.extend_from_slice(&mine);
            } else {
                common.retain(|x| mine.contains(x));
            }
        }
        task.common = common.to_vec();
    }
}

/// Each provider's `conflicts`: the other providers on its component, found
/// by sorting the providers by component.
fn conflicts(graph: &Graph, provs: &mut [Prov]) {
    let mut by_component: Vec<((Sym, Sym), u32)> = provs
        .iter()
        .enumerate()
        .filter_map(|(p, prov)| {
            graph
                .func(prov.item)
                .map(|f| ((f.peis, f.component), p as u32))
        })
        .collect();
    by_component.sort_unstable();
    for group in by_component.chunk_by(|a, b| a.0 == b.0) {
        if group.len() < 2 {
            continue;
        }
        for &(_, p) in group {
            provs[p as usize].conflicts =
                group.iter().map(|&(_, q)| q).filter(|&q| q != p).collect();
        }
    }
}

/// Whether the consumer's input number `input`, of information `info`, is
/// offered by the producer at a sufficient rate.
fn rate_ok(
    engine: &Engine<'_>,
    consumer: ItemId,
    input: usize,
    producer: ItemId,
    info: &GInfo,
) -> bool {
    let c = &engine.ctx.compiled;
    let (Some(cf), Some(pf)) = (engine.graph.func(consumer), engine.graph.func(producer)) else {
        return false;
    };
    // Most inputs ask for no rate: then any output of that information will do.
    let Some(need) = c.funcs[cf.func as usize].inputs[input].hz else {
        return true;
    };
    let args = &engine.graph.item(producer).args;
    c.funcs[pf.func as usize]
        .outputs
        .iter()
        .find(|o| o.grounds_args_to(args, info))
        .is_some_and(|out| out.hz.is_some_and(|offered| offered >= need))
}

/// Whether some provider could, through its inputs' possible feeders, feed itself.
fn has_cycle(provs: &[Prov], needs: &[Need], opts: &[Opt]) -> bool {
    let opts_of = |need: &Need| &opts[need.opts.0 as usize..need.opts.1 as usize];
    // A provider's successors: the providers of each of its needs' options,
    // walked as (need, option) positions.
    let succ = |p: usize, n: usize, o: usize| -> Option<(usize, usize, usize)> {
        let prov = &provs[p];
        let (mut n, mut o) = (n, o);
        while n < prov.needs.len() {
            let need = &needs[prov.first_need as usize + n];
            if let Some(opt) = opts_of(need).get(o) {
                return Some((opt.prov as usize, n, o + 1));
            }
            (n, o) = (n + 1, 0);
        }
        None
    };
    // 0 unvisited, 1 on the stack, 2 done.
    let mut mark = vec![0u8; provs.len()];
    let mut stack: Vec<(usize, usize, usize)> = Vec::new();
    for start in 0..provs.len() {
        if mark[start] != 0 {
            continue;
        }
        stack.push((start, 0, 0));
        mark[start] = 1;
        while let Some(top) = stack.last_mut() {
            let (p, n, o) = *top;
            match succ(p, n, o) {
                Some((q, n, o)) => {
                    (top.1, top.2) = (n, o);
                    match mark[q] {
                        1 => return true,
                        0 => {
                            mark[q] = 1;
                            stack.push((q, 0, 0));
                        }
                        _ => {}
                    }
                }
                None => {
                    mark[p] = 2;
                    stack.pop();
                }
            }
        }
    }
    false
}
