//! A proof, without grounding, that no configuration exists.
//!
//! Grounding builds every task and functionality instance a goal can reach
//! before the search can say that none is admissible. When the answer is
//! "none" and nobody asks why, most of that work can be skipped: this module
//! reads the state once and decides reachability on the domain's schemas, with
//! variables ignored. It is a relaxation of grounding:
//!
//! - a positive precondition literal is *met* when some fact has its
//!   predicate, its arity and its constants; a functionality's literal that
//!   names the functionality's PEIS (and component) must be met by a fact
//!   whose PEIS (and component) is not excluded;
//! - a functionality schema is usable when all its positive literals are met;
//!   negative literals and (in)equalities are taken to hold;
//! - a method is usable when its positive literals are met and each of its
//!   subtasks is usable; a task is usable when one of its methods is (the
//!   least fixpoint of these rules).
//!
//! Every ground instance that grounding finds feasible satisfies these rules
//! with its bindings forgotten, so a goal that is not usable here has no
//! configuration; a goal that is usable may still have none, and is then left
//! to grounding and search.

use rustc_hash::FxHashMap as HashMap;

use ecology_domain::{EcologyState, Name};

use crate::compile::{CLit, CTerm, Callee, Schema, Symbols};
use crate::model::Exclusion;

/// How many facts are read between two looks at the budget.
const FACTS_PER_CHECK: usize = 1024;
/// How many predicates' addresses a pass remembers.
const PREDICATES_SEEN: usize = 16;

/// One positive precondition literal, as the relaxation reads it.
#[derive(Debug)]
struct Lit {
    arity: usize,
    /// The constants: argument position and text.
    consts: Vec<(usize, Name)>,
    /// Where its fact names the functionality's PEIS, and its component.
    peis_at: Option<usize>,
    component_at: Option<usize>,
}

/// The literals of one predicate, found by their first constant.
#[derive(Debug, Default)]
struct Pred {
    name: Name,
    /// Literals with no constant.
    open: Vec<u32>,
    /// For each argument position some literal's first constant is at: the
    /// literals by that constant.
    keyed: Vec<(usize, HashMap<Name, Vec<u32>>)>,
}

/// The domain's schemas as the relaxation reads them; built from the
/// [`Schema`], once per domain (see `planner::Prepared`).
#[derive(Debug, Default)]
pub(crate) struct Relaxed {
    preds: Vec<Pred>,
    lits: Vec<Lit>,
    /// Each functionality's literals, each method's.
    func_lits: Vec<Vec<u32>>,
    method_lits: Vec<Vec<u32>>,
}

impl Relaxed {
    pub(crate) fn new(schema: &Schema) -> Relaxed {
        let syms = &*schema.domain_syms;
        let mut relaxed = Relaxed::default();
        for f in &schema.funcs {
            let lits = f
                .pre
                .iter()
                .filter_map(|l| relaxed.add(l, Some(f.component), syms))
                .collect();
            relaxed.func_lits.push(lits);
        }
        for m in &schema.methods {
            let lits = m
                .pre
                .iter()
                .filter_map(|l| relaxed.add(l, None, syms))
                .collect();
            relaxed.method_lits.push(lits);
        }
        relaxed
    }

    /// Adds a positive literal (of a functionality whose component is in
    /// slots `component`); others are not read.
    fn add(&mut self, lit: &CLit, component: Option<(u16, u16)>, syms: &Symbols) -> Option<u32> {
        let CLit::Pos(atom) = lit else { return None };
        let at = |slot: u16| {
            atom.args
                .iter()
                .position(|t| matches!(t, CTerm::Var(s) if *s == slot))
        };
        let consts: Vec<(usize, Name)> = atom
            .args
            .iter()
            .enumerate()
            .filter_map(|(i, t)| match t {
                CTerm::Const(c) => Some((i, syms.shared(*c).clone())),
                CTerm::Var(_) => None,
            })
            .collect();
        let id = self.lits.len() as u32;
        let name = syms.shared(atom.pred);
        let pred = match self.preds.iter().position(|p| p.name == *name) {
            Some(p) => p,
            None => {
                self.preds.push(Pred {
                    name: name.clone(),
                    ..Pred::default()
                });
                self.preds.len() - 1
            }
        };
        let pred = &mut self.preds[pred];
        match consts.first() {
            None => pred.open.push(id),
            Some((pos, text)) => {
                let keyed = match pred.keyed.iter().position(|(p, _)| p == pos) {
                    Some(k) => k,
                    None => {
                        pred.keyed.push((*pos, HashMap::default()));
                        pred.keyed.len() - 1
                    }
                };
                pred.keyed[keyed]
                    .1
                    .entry(text.clone())
                    .or_default()
                    .push(id);
            }
        }
        self.lits.push(Lit {
            arity: atom.args.len(),
            consts,
            peis_at: component.and_then(|(p, _)| at(p)),
            component_at: component.and_then(|(_, c)| at(c)),
        });
        Some(id)
    }

    /// Whether the relaxation proves that `goal` on `args` has no
    /// configuration in `state` without the `exclusions`; not when `over`
    /// said the budget ran out before the state was read.
    pub(crate) fn proves_none(
        &self,
        schema: &Schema,
        state: &EcologyState,
        goal: Callee,
        args: &[&str],
        exclusions: &[Exclusion],
        over: &dyn Fn() -> bool,
    ) -> bool {
        let excluded = |lit: &Lit, fact: &[Name]| {
            let Some(peis) = lit.peis_at.map(|i| &*fact[i]) else {
                return false;
            };
            let component = lit.component_at.map(|i| &*fact[i]);
            exclusions.iter().any(|e| match e {
                Exclusion::Peis(p) => peis == p,
                Exclusion::Component {
                    peis: p,
                    component: c,
                } => peis == p && component == Some(c.as_str()),
            })
        };
        let meets = |id: u32, fact: &[Name], met: &[bool]| {
            let lit = &self.lits[id as usize];
            !met[id as usize]
                && fact.len() == lit.arity
                && lit.consts.iter().all(|(i, c)| fact[*i] == *c)
                && !excluded(lit, fact)
        };
        let mut met = vec![false; self.lits.len()];
        let mut unmet = self.lits.len();
        // A state's reader shares one `Name` among all uses of a name, so a
        // fact's predicate is mostly found by its address among the few seen.
        let mut seen: Vec<(*const u8, Option<&Pred>)> = Vec::with_capacity(PREDICATES_SEEN);
        for (k, fact) in state.facts().iter().enumerate() {
            if unmet == 0 {
                break;
            }
            if k % FACTS_PER_CHECK == FACTS_PER_CHECK - 1 && over() {
                return false;
            }
            let address = Name::as_ptr(&fact.predicate) as *const u8;
            let pred = match seen.iter().find(|(a, _)| *a == address) {
                Some((_, pred)) => *pred,
                None => {
                    let pred = self.preds.iter().find(|p| p.name == fact.predicate);
                    if seen.len() < PREDICATES_SEEN {
                        seen.push((address, pred));
                    }
                    pred
                }
            };
            let Some(pred) = pred else { continue };
            let keyed = pred
                .keyed
                .iter()
                .filter_map(|(pos, by_const)| fact.args.get(*pos).and_then(|a| by_const.get(a)));
            for &id in pred.open.iter().chain(keyed.flatten()) {
                if meets(id, &fact.args, &met) {
                    met[id as usize] = true;
                    unmet -= 1;
                }
            }
        }
        let all_met = |lits: &[u32]| lits.iter().all(|&id| met[id as usize]);
        let func_ok: Vec<bool> = self.func_lits.iter().map(|l| all_met(l)).collect();
        let mut method_ok = vec![false; schema.methods.len()];
        let mut task_ok = vec![false; schema.tasks.len()];
        let ok = |callee: Callee, task_ok: &[bool]| match callee {
            Callee::Func(f) => func_ok[f as usize],
            Callee::Task(t) => task_ok[t as usize],
        };
        let mut changed = true;
        while changed {
            changed = false;
            for (t, task) in schema.tasks.iter().enumerate() {
                for &m in &task.methods {
                    let method = &schema.methods[m as usize];
                    if !method_ok[m as usize]
                        && all_met(&self.method_lits[m as usize])
                        && method.subtasks.iter().all(|s| ok(s.callee, &task_ok))
                    {
                        method_ok[m as usize] = true;
                        changed |= !task_ok[t];
                        task_ok[t] = true;
                    }
                }
            }
        }
        let usable = match goal {
            Callee::Func(f) => func_ok[f as usize],
            Callee::Task(t) => schema.tasks[t as usize].methods.iter().any(|&m| {
                let method = &schema.methods[m as usize];
                method_ok[m as usize]
                    && method
                        .task_args
                        .iter()
                        .zip(args)
                        .all(|(term, arg)| match term {
                            CTerm::Const(c) => schema.domain_syms.name(*c) == *arg,
                            CTerm::Var(_) => true,
                        })
            }),
        };
        !usable
    }
}
