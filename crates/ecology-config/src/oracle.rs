//! A brute-force enumerator of every admissible configuration: the oracle the
//! planner is tested against, and its baseline in benchmarks.
//!
//! It is written separately from the planner on purpose — strings instead of
//! interned symbols, naive nested-loop precondition matching, every
//! decomposition tree enumerated and checked whole — so that the two agree only
//! if both implement the semantics of DESIGN section 7. It is exponential;
//! use it on small problems only.

use std::collections::{BTreeMap, BTreeSet, HashMap};

use ecology_domain::{Call, Domain, EcologyState, Info, Literal, Method, Param, Term};

use crate::cost::CostModel;
use crate::model::Exclusion;

/// One admissible configuration as the oracle sees it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OracleConfiguration {
    /// Its cost.
    pub cost: u64,
    /// The same text as [`crate::Configuration::signature`].
    pub signature: String,
}

/// Stops enumerating after this many decomposition trees (a guard for tests).
#[derive(Debug, Clone, Copy)]
pub struct Limit(pub usize);

/// Every admissible configuration for `goal`, cheapest first (ties by
/// signature), or `None` when there are more than `limit` decompositions.
pub fn enumerate(
    domain: &Domain,
    state: &EcologyState,
    goal: &Call,
    exclusions: &[Exclusion],
    cost_model: &dyn CostModel,
    limit: Limit,
) -> Option<Vec<OracleConfiguration>> {
    let oracle = Oracle {
        domain,
        state,
        exclusions,
        cost_model,
    };
    let args: Vec<String> = goal.args.iter().map(|t| t.to_string()).collect();
    let trees = oracle.trees(&goal.name, &args, limit.0)?;
    let mut found: BTreeMap<String, u64> = BTreeMap::new();
    for tree in &trees {
        if let Some((signature, cost)) = oracle.assemble(tree) {
            found.insert(signature, cost);
        }
    }
    let mut out: Vec<OracleConfiguration> = found
        .into_iter()
        .map(|(signature, cost)| OracleConfiguration { cost, signature })
        .collect();
    out.sort_by(|a, b| (a.cost, &a.signature).cmp(&(b.cost, &b.signature)));
    Some(out)
}

#[derive(Debug, Clone)]
enum Tree {
    Func {
        name: String,
        args: Vec<String>,
    },
    Task {
        method: usize,
        binding: HashMap<String, String>,
        children: Vec<Tree>,
    },
}

struct Oracle<'a> {
    domain: &'a Domain,
    state: &'a EcologyState,
    exclusions: &'a [Exclusion],
    cost_model: &'a dyn CostModel,
}

fn value(term: &Term, binding: &HashMap<String, String>) -> Option<String> {
    match term {
        Term::Var(v) => binding.get(&**v).cloned(),
        Term::Const(c) => Some(c.to_string()),
    }
}

fn params_binding(params: &[Param], args: &[String]) -> HashMap<String, String> {
    params
        .iter()
        .zip(args)
        .map(|(p, a)| (p.name.to_string(), a.clone()))
        .collect()
}

fn info_text(info: &Info, binding: &HashMap<String, String>) -> String {
    let mut out = format!("({}", info.name);
    for t in &info.args {
        out.push(' ');
        out.push_str(&value(t, binding).unwrap_or_default());
    }
    out.push(')');
    out
}

impl Oracle<'_> {
    fn holds(&self, lit: &Literal, b: &HashMap<String, String>) -> bool {
        let fact = |atom: &ecology_domain::Atom| {
            self.state.facts().iter().any(|f| {
                f.predicate == atom.predicate
                    && f.args.len() == atom.args.len()
                    && f.args
                        .iter()
                        .zip(&atom.args)
                        .all(|(x, t)| value(t, b).as_deref() == Some(&**x))
            })
        };
        match lit {
            Literal::Pos(a) => fact(a),
            Literal::Neg(a) => !fact(a),
            Literal::Eq(x, y, _) => value(x, b) == value(y, b),
            Literal::Neq(x, y, _) => value(x, b) != value(y, b),
        }
    }

    /// Every binding of the method's variables satisfying its precondition.
    fn bindings(&self, method: &Method, args: &[String]) -> Vec<HashMap<String, String>> {
        let mut start = HashMap::new();
        for (t, a) in method.task.args.iter().zip(args) {
            match t {
                Term::Var(v) => {
                    if let Some(old) = start.insert(v.to_string(), a.clone())
                        && old != *a
                    {
                        return Vec::new();
                    }
                }
                Term::Const(c) => {
                    if **c != **a {
                        return Vec::new();
                    }
                }
            }
        }
        let mut partial = vec![start];
        for lit in &method.precondition {
            let Literal::Pos(atom) = lit else { continue };
            let mut next = Vec::new();
            for b in &partial {
                for f in self.state.facts() {
                    if f.predicate != atom.predicate || f.args.len() != atom.args.len() {
                        continue;
                    }
                    let mut nb = b.clone();
                    let ok = atom.args.iter().zip(&f.args).all(|(t, x)| match t {
                        Term::Const(c) => **c == **x,
                        Term::Var(v) => match nb.get(&**v) {
                            Some(y) => **y == **x,
                            None => {
                                nb.insert(v.to_string(), x.to_string());
                                true
                            }
                        },
                    });
                    if ok && !next.contains(&nb) {
                        next.push(nb);
                    }
                }
            }
            partial = next;
        }
        partial
            .into_iter()
            .filter(|b| method.precondition.iter().all(|l| self.holds(l, b)))
            .collect()
    }

    fn func_ok(&self, name: &str, args: &[String]) -> bool {
        let Some(f) = self.domain.functionality(name) else {
            return false;
        };
        let b = params_binding(&f.params, args);
        let peis = b.get(&*f.component.0).cloned().unwrap_or_default();
        let comp = b.get(&*f.component.1).cloned().unwrap_or_default();
        let excluded = self.exclusions.iter().any(|e| match e {
            Exclusion::Peis(p) => *p == peis,
            Exclusion::Component {
                peis: p,
                component: c,
            } => *p == peis && *c == comp,
        });
        !excluded && f.precondition.iter().all(|l| self.holds(l, &b))
    }

    fn trees(&self, name: &str, args: &[String], limit: usize) -> Option<Vec<Tree>> {
        if self.domain.functionality(name).is_some() {
            return Some(if self.func_ok(name, args) {
                vec![Tree::Func {
                    name: name.to_string(),
                    args: args.to_vec(),
                }]
            } else {
                Vec::new()
            });
        }
        let mut out = Vec::new();
        for (mi, method) in self.domain.methods.iter().enumerate() {
            if *method.task.name != *name {
                continue;
            }
            for binding in self.bindings(method, args) {
                // The cartesian product of the subtasks' trees.
                let mut combos: Vec<Vec<Tree>> = vec![Vec::new()];
                for sub in &method.subtasks {
                    let sub_args: Vec<String> = sub
                        .call
                        .args
                        .iter()
                        .map(|t| value(t, &binding).unwrap_or_default())
                        .collect();
                    let options = self.trees(&sub.call.name, &sub_args, limit)?;
                    let mut next = Vec::new();
                    for combo in &combos {
                        for option in &options {
                            let mut c = combo.clone();
                            c.push(option.clone());
                            next.push(c);
                            if next.len() > limit {
                                return None;
                            }
                        }
                    }
                    combos = next;
                }
                for children in combos {
                    out.push(Tree::Task {
                        method: mi,
                        binding: binding.clone(),
                        children,
                    });
                    if out.len() > limit {
                        return None;
                    }
                }
            }
        }
        Some(out)
    }

    /// The functionality leaf providing `info` out of `tree`.
    fn producer<'t>(&self, tree: &'t Tree, info: &str) -> Option<&'t Tree> {
        match tree {
            Tree::Func { .. } => Some(tree),
            Tree::Task {
                method,
                binding,
                children,
            } => {
                let m = &self.domain.methods[*method];
                let r = m
                    .outputs
                    .iter()
                    .find(|r| info_text(&r.info, binding) == info)?;
                let k = m.subtasks.iter().position(|s| s.label == r.label)?;
                self.producer(&children[k], info)
            }
        }
    }

    fn consumers<'t>(&self, tree: &'t Tree, info: &str, out: &mut Vec<&'t Tree>) -> bool {
        match tree {
            Tree::Func { .. } => {
                out.push(tree);
                true
            }
            Tree::Task {
                method,
                binding,
                children,
            } => {
                let m = &self.domain.methods[*method];
                let mut any = false;
                for r in &m.inputs {
                    if info_text(&r.info, binding) == info {
                        let Some(k) = m.subtasks.iter().position(|s| s.label == r.label) else {
                            return false;
                        };
                        if !self.consumers(&children[k], info, out) {
                            return false;
                        }
                        any = true;
                    }
                }
                any
            }
        }
    }

    fn leaves<'t>(tree: &'t Tree, out: &mut Vec<&'t Tree>) {
        match tree {
            Tree::Func { .. } => out.push(tree),
            Tree::Task { children, .. } => children.iter().for_each(|c| Self::leaves(c, out)),
        }
    }

    fn tasks<'t>(tree: &'t Tree, out: &mut Vec<&'t Tree>) {
        if let Tree::Task { children, .. } = tree {
            out.push(tree);
            children.iter().for_each(|c| Self::tasks(c, out));
        }
    }

    /// (peis, component, call text) of a leaf.
    fn leaf_key(&self, leaf: &Tree) -> (String, String, String) {
        let Tree::Func { name, args } = leaf else {
            return Default::default();
        };
        let f = self
            .domain
            .functionality(name)
            .map(|f| (f, params_binding(&f.params, args)));
        let (peis, comp) = f.map_or((String::new(), String::new()), |(f, b)| {
            (
                b.get(&*f.component.0).cloned().unwrap_or_default(),
                b.get(&*f.component.1).cloned().unwrap_or_default(),
            )
        });
        let mut call = format!("({name}");
        for a in args {
            call.push(' ');
            call.push_str(a);
        }
        call.push(')');
        (peis, comp, call)
    }

    fn assemble(&self, tree: &Tree) -> Option<(String, u64)> {
        let mut leaves = Vec::new();
        Self::leaves(tree, &mut leaves);
        // One functionality per component.
        let mut components: BTreeMap<(String, String), String> = BTreeMap::new();
        for leaf in &leaves {
            let (p, c, call) = self.leaf_key(leaf);
            match components.get(&(p.clone(), c.clone())) {
                Some(other) if *other != call => return None,
                _ => {
                    components.insert((p, c), call);
                }
            }
        }
        // Wires: (consumer component, info) → producer component.
        let mut wires: BTreeMap<((String, String), String), (String, String)> = BTreeMap::new();
        let mut tasks = Vec::new();
        Self::tasks(tree, &mut tasks);
        for task in tasks {
            let Tree::Task {
                method,
                binding,
                children,
            } = task
            else {
                continue;
            };
            let m = &self.domain.methods[*method];
            for ch in &m.channels {
                let info = info_text(&ch.info, binding);
                let from = m.subtasks.iter().position(|s| s.label == ch.from)?;
                let to = m.subtasks.iter().position(|s| s.label == ch.to)?;
                let producer = self.producer(&children[from], &info)?;
                let mut consumers = Vec::new();
                if !self.consumers(&children[to], &info, &mut consumers) {
                    return None;
                }
                let (pp, pc, _) = self.leaf_key(producer);
                let out_hz = self.port(producer, &info, true)?;
                for consumer in consumers {
                    let in_hz = self.port(consumer, &info, false)?;
                    if let Some(need) = in_hz
                        && out_hz.is_none_or(|have| have < need)
                    {
                        return None;
                    }
                    let (cp, cc, _) = self.leaf_key(consumer);
                    let key = ((cp, cc), info.clone());
                    match wires.get(&key) {
                        Some(existing) if *existing != (pp.clone(), pc.clone()) => return None,
                        _ => {
                            wires.insert(key, (pp.clone(), pc.clone()));
                        }
                    }
                }
            }
        }
        // Every input connected.
        for leaf in &leaves {
            let Tree::Func { name, args } = leaf else {
                continue;
            };
            let f = self.domain.functionality(name)?;
            let b = params_binding(&f.params, args);
            let (p, c, _) = self.leaf_key(leaf);
            for input in &f.inputs {
                if !wires.contains_key(&((p.clone(), c.clone()), info_text(input, &b))) {
                    return None;
                }
            }
        }
        // Cost and signature.
        let mut cost = 0u64;
        let mut parts: BTreeSet<String> = BTreeSet::new();
        for ((p, c), call) in &components {
            let name = call
                .trim_start_matches('(')
                .split(' ')
                .next()
                .unwrap_or_default();
            let name = name.trim_end_matches(')');
            let default = self.domain.functionality(name).map_or(0, |f| f.cost);
            cost += self
                .cost_model
                .component_cost(p, c, self.state.component_cost(p, c), default);
            parts.insert(format!("{p}:{c}={call}"));
        }
        let mut channels: BTreeSet<String> = BTreeSet::new();
        for (((cp, cc), info), (pp, pc)) in &wires {
            if pp != cp {
                cost += self
                    .cost_model
                    .channel_cost(pp, cp, self.state.channel_cost(pp, cp));
            }
            channels.insert(format!("{pp}:{pc}>{cp}:{cc}{info}"));
        }
        let mut all: Vec<String> = parts.into_iter().collect();
        all.extend(channels);
        Some((all.join(" "), cost))
    }

    /// The rate of the leaf's output (`output` true) or input carrying `info`;
    /// `None` if it has no such port.
    fn port(&self, leaf: &Tree, info: &str, output: bool) -> Option<Option<f64>> {
        let Tree::Func { name, args } = leaf else {
            return None;
        };
        let f = self.domain.functionality(name)?;
        let b = params_binding(&f.params, args);
        let ports = if output { &f.outputs } else { &f.inputs };
        ports
            .iter()
            .find(|i| info_text(i, &b) == info)
            .map(|i| i.hz)
    }
}
