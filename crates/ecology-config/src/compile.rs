//! The compiled problem: interned symbols, indexed facts, and schemas whose
//! variables are slots, so that grounding and search work on integers.

use std::hash::{Hash, Hasher};

use hashbrown::HashTable;
use rustc_hash::{FxHashMap as HashMap, FxHashSet as HashSet, FxHasher};

use ecology_domain::{ComponentCost, Domain, EcologyState, Info, Literal, Name, Term};

/// An interned symbol.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(crate) struct Sym(pub(crate) u32);

/// The symbol table of one planning problem: each name stored once, found
/// through a table of symbols hashed by their names' text. A plan's table
/// shares the domain's (whose symbols come first) and holds only the state's
/// new names, so starting a plan copies nothing.
#[derive(Debug, Default, Clone)]
pub(crate) struct Symbols {
    /// The domain's table, when this is a plan's.
    base: Option<std::sync::Arc<Symbols>>,
    /// How many names `base` has: this table's first symbol.
    offset: u32,
    table: HashTable<Sym>,
    names: Vec<Name>,
}

fn text_hash(name: &str) -> u64 {
    let mut hasher = FxHasher::default();
    name.hash(&mut hasher);
    hasher.finish()
}

impl Symbols {
    fn with_capacity(n: usize) -> Symbols {
        Symbols {
            table: HashTable::with_capacity(n),
            names: Vec::with_capacity(n),
            ..Symbols::default()
        }
    }

    /// A plan's table over the domain's, with room for `n` more names.
    fn over(base: std::sync::Arc<Symbols>, n: usize) -> Symbols {
        Symbols {
            offset: base.len() as u32,
            base: Some(base),
            table: HashTable::with_capacity(n),
            names: Vec::with_capacity(n),
        }
    }

    /// The symbol of a name with hash `hash`, in this table's own names.
    fn find_own(&self, hash: u64, name: &str) -> Option<Sym> {
        let (names, offset) = (&self.names, self.offset);
        self.table
            .find(hash, |&s| &*names[(s.0 - offset) as usize] == name)
            .copied()
    }

    fn find(&self, hash: u64, name: &str) -> Option<Sym> {
        match &self.base {
            Some(base) => base.find_own(hash, name),
            None => None,
        }
        .or_else(|| self.find_own(hash, name))
    }

    /// The symbol of `name`, shared with the domain and state it comes from.
    pub(crate) fn intern(&mut self, name: &Name) -> Sym {
        let hash = text_hash(name);
        if let Some(sym) = self.find(hash, name) {
            return sym;
        }
        let sym = Sym(self.offset + self.names.len() as u32);
        self.names.push(name.clone());
        let (names, offset) = (&self.names, self.offset);
        self.table
            .insert_unique(hash, sym, |&s| text_hash(&names[(s.0 - offset) as usize]));
        sym
    }

    /// The symbol of a name given as text.
    pub(crate) fn intern_str(&mut self, name: &str) -> Sym {
        match self.get(name) {
            Some(sym) => sym,
            None => self.intern(&Name::from(name)),
        }
    }

    pub(crate) fn get(&self, name: &str) -> Option<Sym> {
        self.find(text_hash(name), name)
    }

    /// How many names are interned.
    pub(crate) fn len(&self) -> usize {
        self.offset as usize + self.names.len()
    }

    pub(crate) fn name(&self, sym: Sym) -> &str {
        self.shared(sym)
    }

    /// The name of `sym`, shared: cloning it copies no text.
    pub(crate) fn shared(&self, sym: Sym) -> &Name {
        match &self.base {
            Some(base) if sym.0 < self.offset => &base.names[sym.0 as usize],
            _ => &self.names[(sym.0 - self.offset) as usize],
        }
    }
}

/// A term with variables as slots of the schema's binding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum CTerm {
    Var(u16),
    Const(Sym),
}

impl CTerm {
    pub(crate) fn ground(self, binding: &[Option<Sym>]) -> Option<Sym> {
        match self {
            CTerm::Var(slot) => binding[slot as usize],
            CTerm::Const(sym) => Some(sym),
        }
    }

    /// Its value with each slot's from `slot`; an unbound slot gives a
    /// symbol no name has.
    fn value_by(self, slot: &impl Fn(u16) -> Option<Sym>) -> Sym {
        match self {
            CTerm::Var(s) => slot(s),
            CTerm::Const(sym) => Some(sym),
        }
        .unwrap_or(Sym(u32::MAX))
    }
}

#[derive(Debug, Clone)]
pub(crate) struct CAtom {
    pub(crate) pred: Sym,
    pub(crate) args: Vec<CTerm>,
}

#[derive(Debug, Clone)]
pub(crate) enum CLit {
    Pos(CAtom),
    Neg(CAtom),
    Eq(CTerm, CTerm),
    Neq(CTerm, CTerm),
}

impl CLit {
    fn terms(&self) -> impl Iterator<Item = CTerm> + '_ {
        let (args, pair): (&[CTerm], [Option<CTerm>; 2]) = match self {
            CLit::Pos(a) | CLit::Neg(a) => (&a.args, [None, None]),
            CLit::Eq(a, b) | CLit::Neq(a, b) => (&[], [Some(*a), Some(*b)]),
        };
        args.iter().copied().chain(pair.into_iter().flatten())
    }
}

#[derive(Debug, Clone)]
pub(crate) struct CInfo {
    pub(crate) name: Sym,
    pub(crate) args: Vec<CTerm>,
    pub(crate) hz: Option<f64>,
}

/// A ground information type.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(crate) struct GInfo {
    pub(crate) name: Sym,
    pub(crate) args: Box<[Sym]>,
}

impl GInfo {
    /// `(name arg ...)`, for people.
    pub(crate) fn text(&self, syms: &Symbols) -> String {
        let name = syms.name(self.name);
        let mut out = String::with_capacity(name.len() + 2 + 8 * self.args.len());
        out.push('(');
        out.push_str(name);
        for &a in self.args.iter() {
            out.push(' ');
            out.push_str(syms.name(a));
        }
        out.push(')');
        out
    }
}

impl CInfo {
    pub(crate) fn ground(&self, binding: &[Option<Sym>]) -> GInfo {
        self.ground_by(|slot| binding[slot as usize])
    }

    /// Grounded by a functionality instance's arguments, which bind its
    /// schema's slots in order (as `ground` with each of them `Some`).
    pub(crate) fn ground_args(&self, args: &[Sym]) -> GInfo {
        self.ground_by(|slot| args.get(slot as usize).copied())
    }

    /// Whether grounded by `binding` it is `info` (as `ground`, without
    /// building it).
    pub(crate) fn grounds_to(&self, binding: &[Option<Sym>], info: &GInfo) -> bool {
        self.grounds_by_to(|slot| binding[slot as usize], info)
    }

    /// Whether grounded by a functionality instance's arguments it is `info`
    /// (as `ground_args`, without building it).
    pub(crate) fn grounds_args_to(&self, args: &[Sym], info: &GInfo) -> bool {
        self.grounds_by_to(|slot| args.get(slot as usize).copied(), info)
    }

    fn grounds_by_to(&self, slot: impl Fn(u16) -> Option<Sym>, info: &GInfo) -> bool {
        self.name == info.name
            && self.args.len() == info.args.len()
            && self
                .args
                .iter()
                .zip(info.args.iter())
                .all(|(&t, &a)| t.value_by(&slot) == a)
    }

    /// Grounded with each slot's value from `slot`; unbound slots become a
    /// symbol no name has.
    fn ground_by(&self, slot: impl Fn(u16) -> Option<Sym>) -> GInfo {
        GInfo {
            name: self.name,
            args: self.args.iter().map(|&t| t.value_by(&slot)).collect(),
        }
    }
}

/// What a subtask calls.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum Callee {
    Func(u32),
    Task(u32),
}

#[derive(Debug)]
pub(crate) struct CFunc {
    pub(crate) src: usize,
    pub(crate) component: (u16, u16),
    pub(crate) pre: Vec<CLit>,
    pub(crate) inputs: Vec<CInfo>,
    pub(crate) outputs: Vec<CInfo>,
    pub(crate) cost: u64,
}

#[derive(Debug)]
pub(crate) struct CTask {
    pub(crate) src: usize,
    pub(crate) methods: Vec<u32>,
}

#[derive(Debug)]
pub(crate) struct CSubtask {
    pub(crate) callee: Callee,
    pub(crate) args: Vec<CTerm>,
}

#[derive(Debug)]
pub(crate) struct CMethod {
    pub(crate) src: usize,
    pub(crate) nvars: usize,
    pub(crate) task_args: Vec<CTerm>,
    pub(crate) pre: Vec<CLit>,
    pub(crate) subtasks: Vec<CSubtask>,
    pub(crate) channels: Vec<(u16, u16, CInfo)>,
    pub(crate) inputs: Vec<(CInfo, u16)>,
    pub(crate) outputs: Vec<(CInfo, u16)>,
}

/// The facts of one predicate, their arguments back to back.
#[derive(Debug, Default)]
pub(crate) struct FactList {
    args: Vec<Sym>,
    /// Where each fact's arguments end in `args`.
    ends: Vec<u32>,
}

impl FactList {
    pub(crate) fn len(&self) -> usize {
        self.ends.len()
    }

    pub(crate) fn get(&self, k: usize) -> &[Sym] {
        let start = if k == 0 { 0 } else { self.ends[k - 1] as usize };
        &self.args[start..self.ends[k] as usize]
    }

    pub(crate) fn iter(&self) -> impl Iterator<Item = &[Sym]> {
        (0..self.len()).map(|k| self.get(k))
    }
}

const NO_FACTS: &FactList = &FactList {
    args: Vec::new(),
    ends: Vec::new(),
};

/// The facts of the state, indexed for joins.
///
/// Only predicates that some precondition mentions are indexed: the others
/// (costs, channel costs: most of a large state) are only ever read whole, and
/// indexing them was most of the time spent on small problems. Arguments are
/// stored back to back, one allocation per predicate rather than per fact.
#[derive(Debug, Default)]
pub(crate) struct Facts {
    by_pred: HashMap<Sym, FactList>,
    /// (predicate, argument position, value) → where its facts' indices
    /// into `by_pred[predicate]` are in `postings`.
    index: HashMap<IndexKey, (u32, u32)>,
    /// The indexed facts, key after key, each key's in ascending order.
    postings: Vec<u32>,
    /// While the state is read: each key of each indexed fact, with the
    /// fact, packed by [`pack`] so that they sort as numbers.
    pending: Vec<u128>,
    indexed: HashSet<Sym>,
}

/// (predicate, argument position, value).
type IndexKey = (Sym, u8, Sym);

/// An index key and a fact's place, as one number ordered by key, then place.
fn pack((pred, pos, value): IndexKey, at: u32) -> u128 {
    (pred.0 as u128) << 72 | (pos as u128) << 64 | (value.0 as u128) << 32 | at as u128
}

/// The key of a packed entry.
fn key_of(packed: u128) -> IndexKey {
    (
        Sym((packed >> 72) as u32),
        (packed >> 64) as u8,
        Sym((packed >> 32) as u32),
    )
}

impl Facts {
    /// Adds a fact; the state has no duplicates (`EcologyState` is a set).
    /// Its index entries wait for [`Facts::build_index`].
    fn insert(&mut self, pred: Sym, args: &[Sym]) {
        let list = self.by_pred.entry(pred).or_default();
        let at = list.ends.len() as u32;
        if self.indexed.contains(&pred) {
            for (pos, &arg) in args.iter().enumerate().take(u8::MAX as usize) {
                self.pending.push(pack((pred, pos as u8, arg), at));
            }
        }
        list.args.extend_from_slice(args);
        list.ends.push(list.args.len() as u32);
    }

    /// Indexes the facts inserted: one sort and one list for all keys,
    /// rather than a list per key.
    fn build_index(&mut self) {
        let mut pending = std::mem::take(&mut self.pending);
        pending.sort_unstable();
        self.postings.reserve(pending.len());
        self.index.reserve(pending.len());
        let mut at = 0;
        while at < pending.len() {
            let key = key_of(pending[at]);
            let start = self.postings.len() as u32;
            while at < pending.len() && key_of(pending[at]) == key {
                self.postings.push(pending[at] as u32);
                at += 1;
            }
            self.index.insert(key, (start, self.postings.len() as u32));
        }
    }

    pub(crate) fn holds(&self, pred: Sym, args: &[Sym]) -> bool {
        let candidates = self.candidates_of(pred, args.iter().map(|&a| Some(a)));
        (0..candidates.len()).any(|k| candidates.get(k) == args)
    }

    pub(crate) fn of(&self, pred: Sym) -> &FactList {
        self.by_pred.get(&pred).unwrap_or(NO_FACTS)
    }

    /// Facts of `pred` that may match `pattern`, using the most selective index.
    fn candidates_of(
        &self,
        pred: Sym,
        pattern: impl Iterator<Item = Option<Sym>>,
    ) -> Candidates<'_> {
        let all = self.of(pred);
        if !self.indexed.contains(&pred) {
            return Candidates::All(all);
        }
        let mut best: Option<&[u32]> = None;
        // Positions past the index's reach are checked by the caller.
        for (pos, value) in pattern.enumerate().take(u8::MAX as usize) {
            if let Some(value) = value {
                let list = self
                    .index
                    .get(&(pred, pos as u8, value))
                    .map_or(&[][..], |&(start, end)| {
                        &self.postings[start as usize..end as usize]
                    });
                if best.is_none_or(|b| list.len() < b.len()) {
                    best = Some(list);
                }
            }
        }
        match best {
            Some(list) => Candidates::Indexed(all, list),
            None => Candidates::All(all),
        }
    }
}

enum Candidates<'a> {
    All(&'a FactList),
    Indexed(&'a FactList, &'a [u32]),
}

impl Candidates<'_> {
    fn len(&self) -> usize {
        match self {
            Candidates::All(all) => all.len(),
            Candidates::Indexed(_, list) => list.len(),
        }
    }

    fn get(&self, i: usize) -> &[Sym] {
        match self {
            Candidates::All(all) => all.get(i),
            Candidates::Indexed(all, list) => all.get(list[i] as usize),
        }
    }
}

/// The domain compiled: its schemas with variables as slots and its names
/// interned. It depends on the domain alone, so a [`crate::Planner`] builds it
/// once and every plan starts from it.
#[derive(Debug)]
pub(crate) struct Schema {
    /// The domain's names; a plan's table adds the state's after them.
    pub(crate) domain_syms: std::sync::Arc<Symbols>,
    pub(crate) funcs: Vec<CFunc>,
    pub(crate) tasks: Vec<CTask>,
    pub(crate) methods: Vec<CMethod>,
    pub(crate) callee_by_name: HashMap<ecology_domain::Name, Callee>,
    /// The predicates some precondition looks up: the state's facts of these
    /// are indexed by argument.
    indexed: HashSet<Sym>,
    /// By task: how often each functionality schema can occur in one
    /// decomposition of it, computed the first time a goal asks.
    multiplicity: Vec<std::sync::OnceLock<std::sync::Arc<[u64]>>>,
}

impl Schema {
    /// Whether some precondition of the domain looks up facts of `predicate`.
    pub(crate) fn reads(&self, predicate: &str) -> bool {
        self.domain_syms
            .get(predicate)
            .is_some_and(|sym| self.indexed.contains(&sym))
    }
}

/// A component held by another executive, from the fact
/// `(held PEIS COMPONENT HOLDER FUNCTIONALITY ARG…)`: it may only be shared, running the same.
#[derive(Debug, Clone)]
pub(crate) struct Held {
    pub(crate) holder: Sym,
    pub(crate) func: Sym,
    pub(crate) args: Vec<Sym>,
}

/// The domain and state, compiled.
#[derive(Debug)]
pub(crate) struct Compiled {
    pub(crate) schema: std::sync::Arc<Schema>,
    /// The domain's names, then the state's.
    pub(crate) syms: Symbols,
    pub(crate) facts: Facts,
    /// The state's `cost` facts, (PEIS, component) → cost; the first one counts.
    pub(crate) costs: HashMap<(Sym, Sym), ComponentCost>,
    /// The state's `channel-cost` facts, (from, to) → cost; the first one counts.
    pub(crate) channels: HashMap<(Sym, Sym), u64>,
    /// The state's `held` facts, (PEIS, component) → the instances other executives hold it
    /// running.
    pub(crate) held: HashMap<(Sym, Sym), Vec<Held>>,
    /// Reading the state was cut short by the caller's budget: facts are missing.
    pub(crate) cut: bool,
}

impl std::ops::Deref for Compiled {
    type Target = Schema;

    fn deref(&self) -> &Schema {
        &self.schema
    }
}

/// How deep a decomposition goes: guards grounding and the multiplicities
/// against domains that bypassed validation with a cycle.
pub(crate) const MAX_DEPTH: usize = 256;

/// How many facts are interned or indexed between two looks at the budget.
const FACTS_PER_CHECK: usize = 1024;

/// A schema's variables, numbered in order of first use. Schemas have a few
/// variables, so a list beats a map.
struct Slots<'a> {
    names: Vec<&'a str>,
}

impl<'a> Slots<'a> {
    fn new() -> Slots<'a> {
        Slots { names: Vec::new() }
    }

    fn slot(&mut self, var: &'a str) -> u16 {
        match self.names.iter().position(|&n| n == var) {
            Some(at) => at as u16,
            None => {
                self.names.push(var);
                (self.names.len() - 1) as u16
            }
        }
    }
}

impl Schema {
    /// For each functionality schema, the most times it can occur in one
    /// decomposition of `goal`; a task's are computed once and kept.
    pub(crate) fn multiplicity(&self, goal: Callee) -> std::sync::Arc<[u64]> {
        match goal {
            Callee::Task(t) => self.multiplicity[t as usize]
                .get_or_init(|| multiplicity(self, goal).into())
                .clone(),
            Callee::Func(_) => multiplicity(self, goal).into(),
        }
    }

    /// Compiles the domain's schemas.
    pub(crate) fn new(domain: &Domain) -> Schema {
        let mut callee_by_name = HashMap::default();
        for (i, f) in domain.functionalities.iter().enumerate() {
            callee_by_name.insert(f.name.clone(), Callee::Func(i as u32));
        }
        for (i, t) in domain.tasks.iter().enumerate() {
            callee_by_name.insert(t.name.clone(), Callee::Task(i as u32));
        }
        let mut schema = Schema {
            domain_syms: std::sync::Arc::new(Symbols::with_capacity(64)),
            funcs: Vec::with_capacity(domain.functionalities.len()),
            tasks: Vec::with_capacity(domain.tasks.len()),
            methods: Vec::with_capacity(domain.methods.len()),
            callee_by_name,
            indexed: HashSet::default(),
            multiplicity: (0..domain.tasks.len())
                .map(|_| std::sync::OnceLock::new())
                .collect(),
        };
        for (src, f) in domain.functionalities.iter().enumerate() {
            let mut slots = Slots::new();
            for p in &f.params {
                slots.slot(&p.name);
            }
            let component = (slots.slot(&f.component.0), slots.slot(&f.component.1));
            let func = CFunc {
                src,
                component,
                pre: schema.lits(&f.precondition, &mut slots),
                inputs: schema.infos(&f.inputs, &mut slots),
                outputs: schema.infos(&f.outputs, &mut slots),
                cost: f.cost,
            };
            schema.funcs.push(func);
        }
        for src in 0..domain.tasks.len() {
            schema.tasks.push(CTask {
                src,
                methods: Vec::new(),
            });
        }
        for (src, m) in domain.methods.iter().enumerate() {
            let Some(&Callee::Task(task)) = schema.callee_by_name.get(&m.task.name) else {
                continue;
            };
            let mut slots = Slots::new();
            let task_args = schema.terms(&m.task.args, &mut slots);
            let pre = schema.lits(&m.precondition, &mut slots);
            let mut subtasks = Vec::new();
            for sub in &m.subtasks {
                let Some(&callee) = schema.callee_by_name.get(&sub.call.name) else {
                    continue;
                };
                subtasks.push(CSubtask {
                    callee,
                    args: schema.terms(&sub.call.args, &mut slots),
                });
            }
            let label = |name: &str| {
                m.subtasks
                    .iter()
                    .position(|s| &*s.label == name)
                    .map(|i| i as u16)
            };
            let mut channels = Vec::new();
            for c in &m.channels {
                if let (Some(from), Some(to)) = (label(&c.from), label(&c.to)) {
                    let info = schema.info(&c.info, &mut slots);
                    channels.push((from, to, info));
                }
            }
            let mut inputs = Vec::new();
            for r in &m.inputs {
                if let Some(at) = label(&r.label) {
                    inputs.push((schema.info(&r.info, &mut slots), at));
                }
            }
            let mut outputs = Vec::new();
            for r in &m.outputs {
                if let Some(at) = label(&r.label) {
                    outputs.push((schema.info(&r.info, &mut slots), at));
                }
            }
            // Declared parameters that are never used still get slots, so that
            // the binding shown to people lists them all.
            for p in &m.params {
                slots.slot(&p.name);
            }
            schema.tasks[task as usize]
                .methods
                .push(schema.methods.len() as u32);
            schema.methods.push(CMethod {
                src,
                nvars: slots.names.len(),
                task_args,
                pre,
                subtasks,
                channels,
                inputs,
                outputs,
            });
        }
        let pres = schema.funcs.iter().map(|f| &f.pre);
        let pres = pres.chain(schema.methods.iter().map(|m| &m.pre));
        let mut indexed = HashSet::default();
        for lit in pres.flatten() {
            if let CLit::Pos(a) | CLit::Neg(a) = lit {
                indexed.insert(a.pred);
            }
        }
        schema.indexed = indexed;
        schema
    }

    fn terms<'a>(&mut self, terms: &'a [Term], slots: &mut Slots<'a>) -> Vec<CTerm> {
        terms
            .iter()
            .map(|t| match t {
                Term::Var(v) => CTerm::Var(slots.slot(v)),
                Term::Const(c) => {
                    CTerm::Const(std::sync::Arc::make_mut(&mut self.domain_syms).intern(c))
                }
            })
            .collect()
    }

    fn lits<'a>(&mut self, lits: &'a [Literal], slots: &mut Slots<'a>) -> Vec<CLit> {
        lits.iter()
            .map(|l| match l {
                Literal::Pos(a) => CLit::Pos(CAtom {
                    pred: std::sync::Arc::make_mut(&mut self.domain_syms).intern(&a.predicate),
                    args: self.terms(&a.args, slots),
                }),
                Literal::Neg(a) => CLit::Neg(CAtom {
                    pred: std::sync::Arc::make_mut(&mut self.domain_syms).intern(&a.predicate),
                    args: self.terms(&a.args, slots),
                }),
                Literal::Eq(a, b, _) => {
                    let t = self.terms(std::slice::from_ref(a), slots)[0];
                    let u = self.terms(std::slice::from_ref(b), slots)[0];
                    CLit::Eq(t, u)
                }
                Literal::Neq(a, b, _) => {
                    let t = self.terms(std::slice::from_ref(a), slots)[0];
                    let u = self.terms(std::slice::from_ref(b), slots)[0];
                    CLit::Neq(t, u)
                }
            })
            .collect()
    }

    fn info<'a>(&mut self, info: &'a Info, slots: &mut Slots<'a>) -> CInfo {
        CInfo {
            name: std::sync::Arc::make_mut(&mut self.domain_syms).intern(&info.name),
            args: self.terms(&info.args, slots),
            hz: info.hz,
        }
    }

    fn infos<'a>(&mut self, infos: &'a [Info], slots: &mut Slots<'a>) -> Vec<CInfo> {
        infos.iter().map(|i| self.info(i, slots)).collect()
    }
}

/// For each functionality schema, the most times it can occur in one
/// decomposition of `goal` (computed on schemas, so it holds for every binding).
fn multiplicity(c: &Schema, goal: Callee) -> Vec<u64> {
    /// Fills `memo[t]` with task `t`'s counts (left empty past `MAX_DEPTH`,
    /// which counts as none).
    fn occ(c: &Schema, t: usize, memo: &mut [Option<Vec<u64>>], depth: usize) {
        if memo[t].is_some() || depth >= MAX_DEPTH {
            return;
        }
        let mut out = vec![0u64; c.funcs.len()];
        let mut sum = vec![0u64; c.funcs.len()];
        for &m in &c.tasks[t].methods {
            sum.fill(0);
            for sub in &c.methods[m as usize].subtasks {
                match sub.callee {
                    Callee::Func(f) => sum[f as usize] = sum[f as usize].saturating_add(1),
                    Callee::Task(u) => {
                        occ(c, u as usize, memo, depth + 1);
                        if let Some(counts) = &memo[u as usize] {
                            for (s, o) in sum.iter_mut().zip(counts) {
                                *s = s.saturating_add(*o);
                            }
                        }
                    }
                }
            }
            for (o, s) in out.iter_mut().zip(&sum) {
                *o = (*o).max(*s);
            }
        }
        memo[t] = Some(out);
    }
    match goal {
        Callee::Func(f) => {
            let mut out = vec![0u64; c.funcs.len()];
            out[f as usize] = 1;
            out
        }
        Callee::Task(t) => {
            let mut memo = vec![None; c.tasks.len()];
            occ(c, t as usize, &mut memo, 0);
            memo[t as usize]
                .take()
                .unwrap_or_else(|| vec![0u64; c.funcs.len()])
        }
    }
}

impl Compiled {
    /// Compiles the state against `schema`, asking `over` every
    /// [`FACTS_PER_CHECK`] facts whether the budget ran out; if it did, the
    /// rest of the state is left out and `cut` is set.
    pub(crate) fn new_until(
        schema: std::sync::Arc<Schema>,
        state: &EcologyState,
        over: &dyn Fn() -> bool,
    ) -> Compiled {
        let mut syms = Symbols::over(schema.domain_syms.clone(), state.len());
        let mut facts = Facts {
            indexed: schema.indexed.clone(),
            ..Facts::default()
        };
        facts.pending.reserve(state.len());
        let mut cut = false;
        let mut args = Vec::with_capacity(8);
        // A state's reader shares one `Name` among all uses of a name, so
        // most names are found by their address, without hashing the text.
        // The state outlives this map, so an address names one text.
        let mut by_address: HashMap<usize, Sym> =
            HashMap::with_capacity_and_hasher(state.len(), Default::default());
        let mut intern = |syms: &mut Symbols, name: &Name| {
            *by_address
                .entry(Name::as_ptr(name) as *const u8 as usize)
                .or_insert_with(|| syms.intern(name))
        };
        // Costs and channel costs (most of a large state) are read straight
        // into their tables, their numbers not interned; they are kept as
        // facts too only when a precondition looks them up.
        let (cost, channel_cost) = (syms.intern_str("cost"), syms.intern_str("channel-cost"));
        let held_pred = syms.intern_str("held");
        let mut held: HashMap<(Sym, Sym), Vec<Held>> = HashMap::default();
        let mut costs: HashMap<(Sym, Sym), ComponentCost> =
            HashMap::with_capacity_and_hasher(state.len() / 2, Default::default());
        let mut channels: HashMap<(Sym, Sym), u64> =
            HashMap::with_capacity_and_hasher(state.len() / 2, Default::default());
        for (k, fact) in state.facts().iter().enumerate() {
            if k % FACTS_PER_CHECK == FACTS_PER_CHECK - 1 && over() {
                cut = true;
                break;
            }
            let pred = intern(&mut syms, &fact.predicate);
            if pred == cost || pred == channel_cost {
                match &fact.args[..] {
                    [p, c, amount, power] if pred == cost => {
                        if let Some(value) = ComponentCost::read(amount, power) {
                            let key = (intern(&mut syms, p), intern(&mut syms, c));
                            costs.entry(key).or_insert(value);
                        }
                    }
                    [a, b, n] if pred == channel_cost => {
                        if let Ok(n) = n.parse::<u64>() {
                            let key = (intern(&mut syms, a), intern(&mut syms, b));
                            channels.entry(key).or_insert(n);
                        }
                    }
                    _ => {}
                }
                if !facts.indexed.contains(&pred) {
                    continue;
                }
            }
            args.clear();
            args.extend(fact.args.iter().map(|a| intern(&mut syms, a)));
            if pred == held_pred && args.len() >= 4 {
                held.entry((args[0], args[1])).or_default().push(Held {
                    holder: args[2],
                    func: args[3],
                    args: args[4..].to_vec(),
                });
            }
            facts.insert(pred, &args);
        }
        facts.build_index();
        Compiled {
            schema,
            syms,
            facts,
            costs,
            channels,
            held,
            cut,
        }
    }

    /// Calls `found` with every extension of `binding` that satisfies `lits`.
    pub(crate) fn solve(
        &self,
        lits: &[CLit],
        binding: &mut Vec<Option<Sym>>,
        found: &mut dyn FnMut(&[Option<Sym>]),
    ) {
        let mut done = vec![false; lits.len()];
        self.solve_rec(lits, &mut done, binding, found);
    }

    fn solve_rec(
        &self,
        lits: &[CLit],
        done: &mut [bool],
        binding: &mut Vec<Option<Sym>>,
        found: &mut dyn FnMut(&[Option<Sym>]),
    ) {
        // Checks whose variables are all bound are applied first: they prune.
        for (i, lit) in lits.iter().enumerate() {
            if done[i] || matches!(lit, CLit::Pos(_)) {
                continue;
            }
            if lit.terms().all(|t| t.ground(binding).is_some()) {
                if !self.check(lit, binding) {
                    return;
                }
                done[i] = true;
                self.solve_rec(lits, done, binding, found);
                done[i] = false;
                return;
            }
        }
        // Then the positive literal with the most bound arguments.
        let next = lits
            .iter()
            .enumerate()
            .filter(|(i, l)| !done[*i] && matches!(l, CLit::Pos(_)))
            .max_by_key(|(i, l)| {
                let bound = l.terms().filter(|t| t.ground(binding).is_some()).count();
                (bound, usize::MAX - i)
            });
        let Some((i, CLit::Pos(atom))) = next else {
            // No positive literal is left. A check still open has a variable no
            // literal binds (validation rules that out); it counts as failing.
            if done.iter().all(|d| *d) {
                found(binding);
            }
            return;
        };
        let candidates = self
            .facts
            .candidates_of(atom.pred, atom.args.iter().map(|t| t.ground(binding)));
        done[i] = true;
        // The slots this fact binds: at most one per argument.
        let mut short = [0u16; 8];
        let mut long = Vec::new();
        let newly: &mut [u16] = if atom.args.len() <= short.len() {
            &mut short[..atom.args.len()]
        } else {
            long.resize(atom.args.len(), 0);
            &mut long
        };
        'facts: for k in 0..candidates.len() {
            let fact = candidates.get(k);
            if fact.len() != atom.args.len() {
                continue;
            }
            let mut bound = 0;
            for (term, &value) in atom.args.iter().zip(fact) {
                match term {
                    CTerm::Const(c) if *c != value => {
                        undo(binding, &newly[..bound]);
                        continue 'facts;
                    }
                    CTerm::Const(_) => {}
                    CTerm::Var(slot) => match binding[*slot as usize] {
                        Some(bound_to) if bound_to != value => {
                            undo(binding, &newly[..bound]);
                            continue 'facts;
                        }
                        Some(_) => {}
                        None => {
                            binding[*slot as usize] = Some(value);
                            newly[bound] = *slot;
                            bound += 1;
                        }
                    },
                }
            }
            self.solve_rec(lits, done, binding, found);
            undo(binding, &newly[..bound]);
        }
        done[i] = false;
    }

    /// Evaluates a literal whose terms are all bound.
    pub(crate) fn check(&self, lit: &CLit, binding: &[Option<Sym>]) -> bool {
        let g = |t: &CTerm| t.ground(binding);
        match lit {
            CLit::Pos(a) | CLit::Neg(a) => {
                // Most atoms are short: ground them on the stack.
                let mut short = [Sym(0); 8];
                let holds = if a.args.len() <= short.len() {
                    let mut all = true;
                    for (slot, t) in short.iter_mut().zip(&a.args) {
                        match g(t) {
                            Some(v) => *slot = v,
                            None => all = false,
                        }
                    }
                    all && self.facts.holds(a.pred, &short[..a.args.len()])
                } else {
                    let args: Option<Vec<Sym>> = a.args.iter().map(g).collect();
                    args.is_some_and(|args| self.facts.holds(a.pred, &args))
                };
                holds == matches!(lit, CLit::Pos(_))
            }
            CLit::Eq(a, b) => g(a).is_some() && g(a) == g(b),
            CLit::Neq(a, b) => g(a).is_some() && g(b).is_some() && g(a) != g(b),
        }
    }
}

fn undo(binding: &mut [Option<Sym>], slots: &[u16]) {
    for &slot in slots {
        binding[slot as usize] = None;
    }
}
