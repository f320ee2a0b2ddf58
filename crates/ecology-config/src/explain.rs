//! Why no configuration exists: an explanation tree, and its rendering.
//!
//! Built from the grounded AND-OR graph: for a task instance, each method and
//! binding that was tried and the first subtask it could not provide; for a
//! functionality instance, the excluded component or PEIS or the false
//! precondition. When every decomposition exists but none is admissible, the
//! search's rejection reasons are reported instead.
//!
//! A task instance that several bindings need is explained once, where it
//! first appears; later it says "see above". Otherwise the tree would repeat
//! a shared subtree under each binding, level after level, and grow
//! exponentially with the depth of the domain.

use std::fmt;

use crate::compile::{CLit, CTerm, Sym};
use crate::ground::{
    Ctx, FuncProblem, Graph, INFEASIBLE, ItemId, ItemKind, bind_task_args, substitute_literal,
};

/// How many bindings of one method an explanation shows.
const BINDINGS_SHOWN: usize = 3;
/// How deep an explanation goes.
const MAX_DEPTH: usize = 16;

/// One node of an explanation: what could not be provided, and why.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Explanation {
    /// What it is about: a task or functionality instance, a method, an input.
    pub subject: String,
    /// Why it fails, in plain words.
    pub reason: String,
    /// The failures this one comes from.
    pub causes: Vec<Explanation>,
}

impl Explanation {
    fn leaf(subject: impl Into<String>, reason: impl Into<String>) -> Explanation {
        Explanation {
            subject: subject.into(),
            reason: reason.into(),
            causes: Vec::new(),
        }
    }

    /// Every line of the tree, depth-first; handy for searching in tests.
    pub fn lines(&self) -> Vec<String> {
        self.to_string().lines().map(str::to_string).collect()
    }
}

impl fmt::Display for Explanation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fn write(
            f: &mut fmt::Formatter<'_>,
            e: &Explanation,
            prefix: &str,
            last: bool,
            root: bool,
        ) -> fmt::Result {
            let (branch, rest) = match (root, last) {
                (true, _) => ("", ""),
                (false, true) => ("└─ ", "   "),
                (false, false) => ("├─ ", "│  "),
            };
            if e.subject.is_empty() {
                writeln!(f, "{prefix}{branch}{}", e.reason)?;
            } else {
                writeln!(f, "{prefix}{branch}{}: {}", e.subject, e.reason)?;
            }
            let child_prefix = format!("{prefix}{rest}");
            for (i, cause) in e.causes.iter().enumerate() {
                write(f, cause, &child_prefix, i + 1 == e.causes.len(), false)?;
            }
            Ok(())
        }
        write(f, self, "", true, true)
    }
}

pub(crate) fn describe(ctx: &Ctx<'_>, graph: &Graph, item: ItemId) -> String {
    let item = graph.item(item);
    let mut out = format!("({}", ctx.callee_name(item.callee));
    for &a in item.args.iter() {
        out.push(' ');
        out.push_str(ctx.compiled.syms.name(a));
    }
    out.push(')');
    out
}

/// Explains why `item` cannot be provided (its lower bound is infinite).
/// `explained` marks, by item index, the task instances already explained.
fn explain_item(
    ctx: &Ctx<'_>,
    graph: &Graph,
    item: ItemId,
    depth: usize,
    explained: &mut [bool],
) -> Explanation {
    let subject = describe(ctx, graph, item);
    let c = &ctx.compiled;
    match &graph.item(item).kind {
        ItemKind::Func(f) => {
            let peis = c.syms.name(f.peis);
            let component = c.syms.name(f.component);
            let reason = match f.problem {
                Some(FuncProblem::ComponentExcluded) => {
                    format!("component {peis}:{component} is excluded")
                }
                Some(FuncProblem::PeisExcluded) => format!("PEIS {peis} is excluded"),
                Some(FuncProblem::Held) => {
                    let held = c.held.get(&(f.peis, f.component)).into_iter().flatten();
                    let by: Vec<String> = held
                        .map(|h| {
                            let words: Vec<&str> = std::iter::once(h.func)
                                .chain(h.args.iter().copied())
                                .map(|a| c.syms.name(a))
                                .collect();
                            format!("{} running ({})", c.syms.name(h.holder), words.join(" "))
                        })
                        .collect();
                    format!(
                        "component {peis}:{component} is held by {}",
                        by.join(" and ")
                    )
                }
                Some(FuncProblem::Precondition(i)) => {
                    let schema = &ctx.domain.functionalities[c.funcs[f.func as usize].src];
                    let args: Vec<&str> = graph
                        .item(item)
                        .args
                        .iter()
                        .map(|&a| c.syms.name(a))
                        .collect();
                    let lit = substitute_literal(&schema.precondition[i], &schema.params, &args);
                    let mut reason = format!("precondition {lit} does not hold");
                    if let Some(hint) = missing_type_hint(ctx, &c.funcs[f.func as usize].pre[i]) {
                        reason.push_str(&format!(" ({hint})"));
                    }
                    reason
                }
                None => "it can be provided".to_string(),
            };
            Explanation::leaf(subject, reason)
        }
        ItemKind::Task { task, alts } => {
            let methods = &c.tasks[*task as usize].methods;
            if methods.is_empty() {
                return Explanation::leaf(subject, "no method decomposes this task");
            }
            if std::mem::replace(&mut explained[item.0 as usize], true) {
                return Explanation::leaf(subject, "no method applies (see above)");
            }
            let mut causes = Vec::new();
            for &m in methods {
                let name = ctx.method_name(m);
                let mine: Vec<_> = alts.iter().filter(|a| a.method == m).collect();
                if mine.is_empty() {
                    causes.push(Explanation::leaf(
                        format!("method {name}"),
                        unmet_precondition(ctx, m, &graph.item(item).args),
                    ));
                    continue;
                }
                for alt in mine.iter().take(BINDINGS_SHOWN) {
                    let method = &c.methods[m as usize];
                    let subject = format!("method {name}{}", binding_text(ctx, m, &alt.binding));
                    if alt.lb != INFEASIBLE {
                        continue;
                    }
                    if let Some((i, j)) = alt.clash {
                        let f = graph.func(alt.children[i]).map(|f| (f.peis, f.component));
                        let comp = f.map_or(String::new(), |(p, c2)| {
                            format!("{}:{}", c.syms.name(p), c.syms.name(c2))
                        });
                        causes.push(Explanation::leaf(
                            subject,
                            format!(
                                "{} and {} would both run on component {comp}",
                                describe(ctx, graph, alt.children[i]),
                                describe(ctx, graph, alt.children[j])
                            ),
                        ));
                        continue;
                    }
                    let Some(k) = alt
                        .children
                        .iter()
                        .position(|&ch| graph.item(ch).lb == INFEASIBLE)
                    else {
                        continue;
                    };
                    let child = alt.children[k];
                    let label = ctx.subtask_label(m, k as u16);
                    // Say which input goes missing when the failed subtask feeds another.
                    let feeds = method
                        .channels
                        .iter()
                        .find(|(from, _, _)| *from as usize == k);
                    let reason = match feeds {
                        Some((_, to, info)) => {
                            let text = info.ground(&alt.binding).text(&c.syms);
                            let to_child = alt.children.get(*to as usize).copied();
                            format!(
                                "input {text} of {} {} cannot be provided by {label}",
                                ctx.subtask_label(m, *to),
                                to_child.map_or(String::new(), |t| describe(ctx, graph, t)),
                            )
                        }
                        None => match method.outputs.iter().find(|(_, sub)| *sub as usize == k) {
                            Some((info, _)) => {
                                let text = info.ground(&alt.binding).text(&c.syms);
                                format!("output {text} cannot be provided by {label}")
                            }
                            None => format!("subtask {label} cannot be provided"),
                        },
                    };
                    let causes_below = if depth < MAX_DEPTH {
                        vec![explain_item(ctx, graph, child, depth + 1, explained)]
                    } else {
                        Vec::new()
                    };
                    causes.push(Explanation {
                        subject,
                        reason,
                        causes: causes_below,
                    });
                }
                if mine.len() > BINDINGS_SHOWN {
                    causes.push(Explanation::leaf(
                        "",
                        format!(
                            "… and {} more bindings of method {name}",
                            mine.len() - BINDINGS_SHOWN
                        ),
                    ));
                }
            }
            Explanation {
                subject,
                reason: "no method applies".to_string(),
                causes,
            }
        }
    }
}

/// ` with ?p = hsm, ?t = tr1` for the variables a method binds beyond its task.
fn binding_text(ctx: &Ctx<'_>, m: u32, binding: &[Option<Sym>]) -> String {
    let c = &ctx.compiled;
    let method = &c.methods[m as usize];
    let domain_method = &ctx.domain.methods[method.src];
    let task_vars: Vec<&str> = domain_method
        .task
        .args
        .iter()
        .filter_map(|t| t.var())
        .collect();
    let mut parts = Vec::new();
    // Slots were given to variables in order of first appearance; recover names.
    for (slot, name) in slot_names(ctx, m).iter().enumerate() {
        if task_vars.contains(&name.as_str()) {
            continue;
        }
        if let Some(Some(v)) = binding.get(slot) {
            parts.push(format!("?{name} = {}", c.syms.name(*v)));
        }
    }
    if parts.is_empty() {
        String::new()
    } else {
        format!(" with {}", parts.join(", "))
    }
}

/// The variable names of a method, by slot.
fn slot_names(ctx: &Ctx<'_>, m: u32) -> Vec<String> {
    let method = &ctx.domain.methods[ctx.compiled.methods[m as usize].src];
    let mut names: Vec<String> = Vec::new();
    let mut see = |t: &ecology_domain::Term| {
        if let Some(v) = t.var()
            && !names.iter().any(|n| n == v)
        {
            names.push(v.to_string());
        }
    };
    // The same order as compilation: task args, precondition, subtasks,
    // channels, inputs, outputs, then declared parameters.
    method.task.args.iter().for_each(&mut see);
    for lit in &method.precondition {
        lit.terms().for_each(&mut see);
    }
    for sub in &method.subtasks {
        sub.call.args.iter().for_each(&mut see);
    }
    for ch in &method.channels {
        ch.info.args.iter().for_each(&mut see);
    }
    for r in method.inputs.iter().chain(&method.outputs) {
        r.info.args.iter().for_each(&mut see);
    }
    for p in &method.params {
        if !names.iter().any(|n| *n == *p.name) {
            names.push(p.name.to_string());
        }
    }
    names
}

/// The first precondition literal of method `m` that no binding satisfies,
/// with the task's arguments in place.
fn unmet_precondition(ctx: &Ctx<'_>, m: u32, args: &[Sym]) -> String {
    let c = &ctx.compiled;
    let method = &c.methods[m as usize];
    let domain_method = &ctx.domain.methods[method.src];
    let Some(binding) = bind_task_args(method, args) else {
        return format!("its task {} does not match", domain_method.task);
    };
    let names = slot_names(ctx, m);
    let bound_text: Vec<String> = binding
        .iter()
        .enumerate()
        .filter_map(|(slot, v)| {
            v.map(|v| {
                format!(
                    "?{} = {}",
                    names.get(slot).map_or("?", |s| s),
                    c.syms.name(v)
                )
            })
        })
        .collect();
    let with = if bound_text.is_empty() {
        String::new()
    } else {
        format!(" with {}", bound_text.join(", "))
    };
    for k in 1..=method.pre.len() {
        // Checks whose variables the prefix does not bind yet are left for later.
        let mut bindable: Vec<bool> = binding.iter().map(Option::is_some).collect();
        for lit in &method.pre[..k] {
            if let CLit::Pos(a) = lit {
                for t in &a.args {
                    if let CTerm::Var(s) = t {
                        bindable[*s as usize] = true;
                    }
                }
            }
        }
        let prefix: Vec<CLit> = method.pre[..k]
            .iter()
            .filter(|lit| match lit {
                CLit::Pos(_) => true,
                CLit::Neg(a) => a.args.iter().all(|t| slot_bound(t, &bindable)),
                CLit::Eq(a, b) | CLit::Neq(a, b) => {
                    slot_bound(a, &bindable) && slot_bound(b, &bindable)
                }
            })
            .cloned()
            .collect();
        let mut any = false;
        let mut b = binding.clone();
        c.solve(&prefix, &mut b, &mut |_| any = true);
        if !any {
            let lit = &domain_method.precondition[k - 1];
            let mut reason = format!("precondition {lit} does not hold{with}");
            if let Some(hint) = missing_type_hint(ctx, &method.pre[k - 1]) {
                reason.push_str(&format!(" ({hint})"));
            }
            return reason;
        }
    }
    format!("its precondition does not hold{with}")
}

fn slot_bound(t: &CTerm, bindable: &[bool]) -> bool {
    match t {
        CTerm::Var(s) => bindable[*s as usize],
        CTerm::Const(_) => true,
    }
}

/// "no component of type X in the ecology" when a `(pc ?p X ?c)` literal names
/// a type no component has.
fn missing_type_hint(ctx: &Ctx<'_>, lit: &CLit) -> Option<String> {
    let c = &ctx.compiled;
    let CLit::Pos(atom) = lit else { return None };
    if c.syms.name(atom.pred) != "pc" {
        return None;
    }
    let CTerm::Const(ty) = *atom.args.get(1)? else {
        return None;
    };
    let exists = c.facts.of(atom.pred).iter().any(|f| f.get(1) == Some(&ty));
    (!exists).then(|| format!("the ecology has no component of type {}", c.syms.name(ty)))
}

/// Explains a search that ended without an admissible configuration.
pub(crate) fn explain(
    ctx: &Ctx<'_>,
    graph: &Graph,
    root: ItemId,
    rejections: &[(String, u64)],
) -> Explanation {
    if graph.item(root).lb == INFEASIBLE {
        let mut explained = vec![false; graph.items.len()];
        let mut e = explain_item(ctx, graph, root, 0, &mut explained);
        e.subject = format!("no configuration for {}", e.subject);
        return e;
    }
    let subject = format!("no configuration for {}", describe(ctx, graph, root));
    let causes = rejections
        .iter()
        .map(|(reason, n)| {
            let times = if *n == 1 {
                String::new()
            } else {
                format!(" ({n} decompositions)")
            };
            Explanation::leaf("", format!("{reason}{times}"))
        })
        .collect();
    Explanation {
        subject,
        reason: "every decomposition is inadmissible".to_string(),
        causes,
    }
}
