//! Grounding: the reachable AND-OR graph of task and functionality instances,
//! with an admissible lower bound on the cost of each.
//!
//! A ground task instance has one alternative per applicable method and
//! binding of its precondition; a ground functionality instance is a leaf that
//! names its component and cost. The lower bound of an instance is the cheapest
//! way to provide it in isolation, with every functionality occurrence charged
//! its cost divided by how often its schema can occur in one configuration.
//! Dividing keeps the bound admissible under component sharing (a component
//! used k times is paid once, and k never exceeds that count); when no schema
//! can occur twice, the bound is exact for conflict-free configurations.

use std::hash::{Hash, Hasher};

use hashbrown::HashTable;
use rustc_hash::{FxHashMap as HashMap, FxHashSet as HashSet, FxHasher};

use ecology_domain::{ComponentCost, Domain, Literal, Name, Param, Power, Term};

use crate::compile::{CMethod, CTerm, Callee, Compiled, MAX_DEPTH, Sym};
use crate::cost::CostModel;

/// "Cannot be provided."
pub(crate) const INFEASIBLE: u64 = u64::MAX;

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(crate) struct ItemId(pub(crate) u32);

/// Why a functionality instance cannot be used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum FuncProblem {
    ComponentExcluded,
    PeisExcluded,
    /// Another executive holds the component running another instance (a `held` fact).
    Held,
    /// The precondition literal at this index is false.
    Precondition(usize),
}

#[derive(Debug)]
pub(crate) struct FuncItem {
    pub(crate) func: u32,
    pub(crate) peis: Sym,
    pub(crate) component: Sym,
    /// What the cost model charges for it.
    pub(crate) cost: u64,
    /// `cost` divided by the multiplicity of its schema: what the bounds charge.
    pub(crate) share: u64,
    pub(crate) power: Power,
    pub(crate) problem: Option<FuncProblem>,
}

/// One way to decompose a task instance: a method, a binding, the children.
#[derive(Debug)]
pub(crate) struct Alt {
    pub(crate) method: u32,
    pub(crate) binding: Box<[Option<Sym>]>,
    pub(crate) children: Box<[ItemId]>,
    pub(crate) lb: u64,
    /// Two children that would run different functionalities on one component.
    pub(crate) clash: Option<(usize, usize)>,
}

#[derive(Debug)]
pub(crate) enum ItemKind {
    Func(FuncItem),
    Task { task: u32, alts: Vec<Alt> },
}

#[derive(Debug)]
pub(crate) struct Item {
    pub(crate) callee: Callee,
    pub(crate) args: Box<[Sym]>,
    pub(crate) kind: ItemKind,
    pub(crate) lb: u64,
}

/// Components and PEIS the planner must not use.
#[derive(Debug, Default)]
pub(crate) struct Excluded {
    pub(crate) components: HashSet<(Sym, Sym)>,
    pub(crate) peis: HashSet<Sym>,
}

/// What grounding reads: the compiled problem, exclusions, costs.
pub(crate) struct Ctx<'a> {
    pub(crate) domain: &'a Domain,
    pub(crate) compiled: Compiled,
    pub(crate) cost_model: &'a dyn CostModel,
    pub(crate) excluded: Excluded,
    costs: HashMap<(Sym, Sym), ComponentCost>,
    /// The state's `channel-cost` facts, (from, to) → cost; the first one counts.
    pub(crate) channels: HashMap<(Sym, Sym), u64>,
    /// How often each functionality schema can occur in one configuration.
    pub(crate) multiplicity: std::sync::Arc<[u64]>,
}

impl<'a> Ctx<'a> {
    pub(crate) fn new(
        domain: &'a Domain,
        mut compiled: Compiled,
        cost_model: &'a dyn CostModel,
        excluded: Excluded,
        goal: Callee,
    ) -> Ctx<'a> {
        let costs = std::mem::take(&mut compiled.costs);
        let channels = std::mem::take(&mut compiled.channels);
        let multiplicity = compiled.schema.multiplicity(goal);
        Ctx {
            domain,
            compiled,
            cost_model,
            excluded,
            costs,
            channels,
            multiplicity,
        }
    }

    /// The functionality's or task's name, shared with the domain.
    pub(crate) fn callee_name(&self, callee: Callee) -> &'a Name {
        match callee {
            Callee::Func(f) => {
                &self.domain.functionalities[self.compiled.funcs[f as usize].src].name
            }
            Callee::Task(t) => &self.domain.tasks[self.compiled.tasks[t as usize].src].name,
        }
    }

    pub(crate) fn method_name(&self, method: u32) -> &'a str {
        &self.domain.methods[self.compiled.methods[method as usize].src].name
    }

    pub(crate) fn subtask_label(&self, method: u32, k: u16) -> &'a str {
        let m = &self.domain.methods[self.compiled.methods[method as usize].src];
        m.subtasks.get(k as usize).map_or("?", |s| &*s.label)
    }

    /// The functionality's postcondition with its parameters replaced by `args`.
    pub(crate) fn ground_postcondition(&self, func: u32, args: &[Sym]) -> Vec<Name> {
        let f = &self.domain.functionalities[self.compiled.funcs[func as usize].src];
        if f.postcondition.is_empty() {
            return Vec::new();
        }
        let names: Vec<&str> = args.iter().map(|&a| self.compiled.syms.name(a)).collect();
        f.postcondition
            .iter()
            .map(|lit| Name::from(substitute_literal(lit, &f.params, &names)))
            .collect()
    }

    /// The channel cost from one PEIS to another under the cost model.
    pub(crate) fn channel_cost(&self, from: Sym, to: Sym) -> u64 {
        let c = &self.compiled;
        let state = self.channels.get(&(from, to)).copied();
        self.cost_model
            .channel_cost(c.syms.name(from), c.syms.name(to), state)
    }

    /// Whether another executive holds component (`peis`, `component`) running something other
    /// than functionality `func` on `args`: then this instance cannot use it. One held running
    /// exactly this instance can be shared.
    fn held_otherwise(&self, func: u32, peis: Sym, component: Sym, args: &[Sym]) -> bool {
        let Some(held) = self.compiled.held.get(&(peis, component)) else {
            return false;
        };
        let name = &self.domain.functionalities[self.compiled.funcs[func as usize].src].name;
        held.iter()
            .any(|h| self.compiled.syms.name(h.func) != &**name || h.args != args)
    }

    fn func_item(&self, func: u32, args: &[Sym]) -> FuncItem {
        let c = &self.compiled;
        let schema = &c.funcs[func as usize];
        // Most functionalities have few parameters: bind them on the stack.
        let mut short = [None; 8];
        let long: Vec<Option<Sym>>;
        let binding: &[Option<Sym>] = if args.len() <= short.len() {
            for (slot, &a) in short.iter_mut().zip(args) {
                *slot = Some(a);
            }
            &short[..args.len()]
        } else {
            long = args.iter().map(|&a| Some(a)).collect();
            &long
        };
        let peis = args[schema.component.0 as usize];
        let component = args[schema.component.1 as usize];
        let state = self.costs.get(&(peis, component)).copied();
        let cost = self.cost_model.component_cost(
            c.syms.name(peis),
            c.syms.name(component),
            state,
            schema.cost,
        );
        let problem = if self.excluded.peis.contains(&peis) {
            Some(FuncProblem::PeisExcluded)
        } else if self.excluded.components.contains(&(peis, component)) {
            Some(FuncProblem::ComponentExcluded)
        } else if self.held_otherwise(func, peis, component, args) {
            Some(FuncProblem::Held)
        } else {
            schema
                .pre
                .iter()
                .position(|lit| !c.check(lit, binding))
                .map(FuncProblem::Precondition)
        };
        FuncItem {
            func,
            peis,
            component,
            cost,
            share: cost / self.multiplicity[func as usize].max(1),
            power: state.map_or(Power::Off, |s| s.power),
            problem,
        }
    }
}

/// The hash under which an instance of `callee` on `args` is memoized.
fn memo_hash(callee: Callee, args: &[Sym]) -> u64 {
    let mut hasher = FxHasher::default();
    callee.hash(&mut hasher);
    args.hash(&mut hasher);
    hasher.finish()
}

/// The grounded AND-OR graph, grown on demand and memoized.
#[derive(Debug, Default)]
pub(crate) struct Graph {
    pub(crate) items: Vec<Item>,
    /// Instances by callee and arguments, hashed by those (see
    /// [`memo_hash`]): found without allocating a key, stored without a
    /// second copy of the arguments.
    memo: HashTable<ItemId>,
    /// Alternatives created, for statistics.
    pub(crate) alternatives: u64,
    /// Grounding was cut short by the caller's budget: the graph is unusable.
    pub(crate) cut: bool,
}

impl Graph {
    /// An empty graph with room for `items` items before it grows.
    pub(crate) fn with_capacity(items: usize) -> Graph {
        Graph {
            items: Vec::with_capacity(items),
            memo: HashTable::with_capacity(items),
            ..Graph::default()
        }
    }

    pub(crate) fn item(&self, id: ItemId) -> &Item {
        &self.items[id.0 as usize]
    }

    pub(crate) fn func(&self, id: ItemId) -> Option<&FuncItem> {
        match &self.item(id).kind {
            ItemKind::Func(f) => Some(f),
            ItemKind::Task { .. } => None,
        }
    }

    /// The instance of `callee` on `args`, grounded with its lower bound,
    /// asking `over` now and then whether the budget ran out; if so, stops
    /// with `cut` set.
    pub(crate) fn ground_until(
        &mut self,
        ctx: &Ctx<'_>,
        callee: Callee,
        args: &[Sym],
        over: &dyn Fn() -> bool,
    ) -> ItemId {
        self.ground_at(ctx, callee, args, 0, over)
    }

    fn ground_at(
        &mut self,
        ctx: &Ctx<'_>,
        callee: Callee,
        args: &[Sym],
        depth: usize,
        over: &dyn Fn() -> bool,
    ) -> ItemId {
        let hash = memo_hash(callee, args);
        let items = &self.items;
        if let Some(&id) = self.memo.find(hash, |&id| {
            let item = &items[id.0 as usize];
            item.callee == callee && *item.args == *args
        }) {
            return id;
        }
        if self.items.len() % 256 == 255 && !self.cut && over() {
            self.cut = true;
        }
        let kind = match callee {
            Callee::Func(func) => ItemKind::Func(ctx.func_item(func, args)),
            Callee::Task(task) if depth < MAX_DEPTH && !self.cut => ItemKind::Task {
                task,
                alts: self.alternatives(ctx, task, args, depth, over),
            },
            Callee::Task(task) => ItemKind::Task {
                task,
                alts: Vec::new(),
            },
        };
        let lb = match &kind {
            ItemKind::Func(f) if f.problem.is_some() => INFEASIBLE,
            ItemKind::Func(f) => f.share,
            ItemKind::Task { alts, .. } => alts.iter().map(|a| a.lb).min().unwrap_or(INFEASIBLE),
        };
        let id = ItemId(self.items.len() as u32);
        self.items.push(Item {
            callee,
            args: args.into(),
            kind,
            lb,
        });
        let items = &self.items;
        self.memo.insert_unique(hash, id, |&id| {
            let item = &items[id.0 as usize];
            memo_hash(item.callee, &item.args)
        });
        id
    }

    fn alternatives(
        &mut self,
        ctx: &Ctx<'_>,
        task: u32,
        args: &[Sym],
        depth: usize,
        over: &dyn Fn() -> bool,
    ) -> Vec<Alt> {
        let c = &ctx.compiled;
        let mut alts = Vec::new();
        for &m in &c.tasks[task as usize].methods {
            let method = &c.methods[m as usize];
            let mut bindings: Vec<Box<[Option<Sym>]>> = Vec::new();
            if let Some(mut binding) = bind_task_args(method, args) {
                c.solve(&method.pre, &mut binding, &mut |b| bindings.push(b.into()));
            }
            let mut sub_args = Vec::new();
            for binding in bindings {
                self.alternatives += 1;
                let mut children = Vec::with_capacity(method.subtasks.len());
                for sub in &method.subtasks {
                    sub_args.clear();
                    // Validation guarantees every subtask argument is bound.
                    if !sub.args.iter().all(|t| match t.ground(&binding) {
                        Some(a) => {
                            sub_args.push(a);
                            true
                        }
                        None => false,
                    }) {
                        continue;
                    }
                    children.push(self.ground_at(ctx, sub.callee, &sub_args, depth + 1, over));
                }
                let clash = self.clash(&children);
                let lb = if clash.is_some() {
                    INFEASIBLE
                } else {
                    children
                        .iter()
                        .try_fold(0u64, |sum, &ch| match self.item(ch).lb {
                            INFEASIBLE => None,
                            lb => Some(sum.saturating_add(lb)),
                        })
                        .unwrap_or(INFEASIBLE)
                };
                alts.push(Alt {
                    method: m,
                    binding,
                    children: children.into(),
                    lb,
                    clash,
                });
            }
        }
        alts
    }

    /// Two functionality children on one component running different instances.
    fn clash(&self, children: &[ItemId]) -> Option<(usize, usize)> {
        for (i, &a) in children.iter().enumerate() {
            let Some(fa) = self.func(a) else { continue };
            for (j, &b) in children.iter().enumerate().skip(i + 1) {
                if a == b {
                    continue;
                }
                if let Some(fb) = self.func(b)
                    && (fa.peis, fa.component) == (fb.peis, fb.component)
                {
                    return Some((i, j));
                }
            }
        }
        None
    }
}

/// The method's binding with its task arguments set, or `None` if a constant
/// in the method's `:task` does not match.
pub(crate) fn bind_task_args(method: &CMethod, args: &[Sym]) -> Option<Vec<Option<Sym>>> {
    let mut binding = vec![None; method.nvars];
    for (term, &arg) in method.task_args.iter().zip(args) {
        match *term {
            CTerm::Const(c) if c != arg => return None,
            CTerm::Const(_) => {}
            CTerm::Var(slot) => match binding[slot as usize] {
                Some(bound) if bound != arg => return None,
                _ => binding[slot as usize] = Some(arg),
            },
        }
    }
    Some(binding)
}

/// Renders a literal with parameters replaced by values (unknown variables stay).
pub(crate) fn substitute_literal(lit: &Literal, params: &[Param], values: &[&str]) -> String {
    let mut out = String::with_capacity(32);
    let term = |out: &mut String, t: &Term| match t {
        Term::Var(v) => match params.iter().position(|p| p.name == *v) {
            Some(i) if i < values.len() => out.push_str(values[i]),
            _ => {
                out.push('?');
                out.push_str(v);
            }
        },
        Term::Const(c) => out.push_str(c),
    };
    let call = |out: &mut String, pred: &str, args: &[Term]| {
        out.push('(');
        out.push_str(pred);
        for a in args {
            out.push(' ');
            term(out, a);
        }
        out.push(')');
    };
    match lit {
        Literal::Pos(a) => call(&mut out, &a.predicate, &a.args),
        Literal::Neg(a) => {
            out.push_str("(not ");
            call(&mut out, &a.predicate, &a.args);
            out.push(')');
        }
        Literal::Eq(a, b, _) | Literal::Neq(a, b, _) => {
            let neq = matches!(lit, Literal::Neq(..));
            out.push_str(if neq { "(not (= " } else { "(= " });
            term(&mut out, a);
            out.push(' ');
            term(&mut out, b);
            out.push_str(if neq { "))" } else { ")" });
        }
    }
    out
}
