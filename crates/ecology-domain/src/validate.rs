//! Semantic checks of a parsed domain: names, arities, bindings, channels, recursion.
//!
//! Runs after parsing and before anything plans with the domain, so the
//! planners can trust that every name resolves, every variable is bound and no
//! task decomposes into itself.

use std::collections::{HashMap, HashSet};

use crate::diagnostic::{Diagnostic, Span};
use crate::model::*;

mod uncertain;

/// Facts of the ecology state with a fixed meaning, and their arities.
pub const ECOLOGY_PREDICATES: &[(&str, usize)] = &[
    ("peis", 1),
    ("pc", 3),
    ("cost", 4),
    ("status", 3),
    ("channel-cost", 3),
];

/// A subtask's target, resolved.
#[derive(Clone, Copy)]
enum Callee<'a> {
    Functionality(&'a Functionality),
    Task(&'a Task),
}

/// Validates `domain` and fills its name index; returns what is wrong.
pub(crate) fn validate(domain: &mut Domain) -> Vec<Diagnostic> {
    let mut v = Validator::default();
    domain.index = v.index(domain);
    for functionality in &domain.functionalities {
        v.functionality(domain, functionality);
    }
    for task in &domain.tasks {
        v.unique_params(&task.params, &format!("task `{}`", task.name));
        let params = names(&task.params);
        for info in task.inputs.iter().chain(&task.outputs) {
            v.vars_declared(
                &info.args,
                info.span,
                &params,
                &format!("task `{}`", task.name),
            );
        }
    }
    for method in &domain.methods {
        v.method(domain, method);
    }
    for action in &domain.actions {
        v.action(domain, action);
        v.uncertain_action(domain, action);
    }
    v.recursion(domain);
    v.information(domain);
    v.diags
}

fn names(params: &[Param]) -> HashSet<&str> {
    params.iter().map(|p| &*p.name).collect()
}

/// The check that a method's variables are bound: by its task's arguments or
/// a positive precondition (else no grounding can give them a value). Each
/// variable is reported once per place.
struct Unbound<'a> {
    method: &'a Method,
    /// The method's parameters.
    params: HashSet<&'a str>,
    /// The parameters the task's arguments and positive preconditions bind.
    bound: HashSet<&'a str>,
    reported: HashSet<(String, usize)>,
}

impl<'a> Unbound<'a> {
    fn new(method: &'a Method, params: HashSet<&'a str>) -> Self {
        let mut bound: HashSet<&str> = method.task.args.iter().filter_map(Term::var).collect();
        for literal in &method.precondition {
            if let Literal::Pos(atom) = literal {
                bound.extend(atom.args.iter().filter_map(Term::var));
            }
        }
        Unbound {
            method,
            params,
            bound,
            reported: HashSet::new(),
        }
    }

    /// Reports each variable among `terms` (at `span`) that is not a
    /// parameter of the method, and each parameter that nothing binds.
    fn terms(&mut self, v: &mut Validator, terms: &[Term], span: Span, what: &str) {
        v.vars_declared(terms, span, &self.params, what);
        self.check(v, terms, span);
    }

    /// Reports each parameter among `terms` (at `span`) that nothing binds.
    fn check(&mut self, v: &mut Validator, terms: &[Term], span: Span) {
        for term in terms {
            if let Term::Var(var) = term
                && self.params.contains(&**var)
                && !self.bound.contains(&**var)
                && self.reported.insert((var.to_string(), span.start))
            {
                v.diags.push(
                    Diagnostic::error(
                        span,
                        format!(
                            "variable `?{var}` is bound neither by the task `{}` nor by a precondition",
                            self.method.task
                        ),
                    )
                    .with_note(format!(
                        "a positive precondition such as `(pc ?p TYPE ?{var})` binds it"
                    )),
                );
            }
        }
    }
}

#[derive(Default)]
struct Validator {
    diags: Vec<Diagnostic>,
}

impl Validator {
    fn error(&mut self, span: Span, message: impl Into<String>) {
        self.diags.push(Diagnostic::error(span, message));
    }

    fn duplicate(&mut self, what: &str, name: &str, span: Span, first: Span) {
        self.diags.push(
            Diagnostic::error(span, format!("duplicate {what} `{name}`"))
                .with_secondary(first, "first defined here"),
        );
    }

    /// Each information type is declared once, and is one that a functionality reads or writes.
    fn information(&mut self, domain: &Domain) {
        let mut seen: HashMap<&str, Span> = HashMap::new();
        for info in &domain.information {
            if let Some(&first) = seen.get(&*info.name) {
                self.duplicate("information", &info.name, info.name_span, first);
                continue;
            }
            seen.insert(&info.name, info.name_span);
            let used = domain
                .functionalities
                .iter()
                .flat_map(|f| f.inputs.iter().chain(&f.outputs))
                .any(|i| i.name == info.name);
            if !used {
                self.error(
                    info.name_span,
                    format!(
                        "information `{}` is neither an input nor an output of any functionality",
                        info.name
                    ),
                );
            }
        }
    }

    fn index(&mut self, domain: &Domain) -> Index {
        let mut index = Index::default();
        // Functionalities and tasks share a namespace: subtasks name either.
        let mut callables: HashMap<&str, Span> = HashMap::new();
        for (i, f) in domain.functionalities.iter().enumerate() {
            match callables.get(&*f.name) {
                Some(&first) => self.duplicate("name", &f.name, f.name_span, first),
                None => {
                    callables.insert(&f.name, f.name_span);
                    index.functionalities.insert(f.name.clone(), i);
                }
            }
        }
        for (i, t) in domain.tasks.iter().enumerate() {
            match callables.get(&*t.name) {
                Some(&first) => self.duplicate("name", &t.name, t.name_span, first),
                None => {
                    callables.insert(&t.name, t.name_span);
                    index.tasks.insert(t.name.clone(), i);
                }
            }
        }
        let mut methods: HashMap<&str, Span> = HashMap::new();
        for (i, m) in domain.methods.iter().enumerate() {
            if let Some(&first) = methods.get(&*m.name) {
                self.duplicate("method", &m.name, m.name_span, first);
                continue;
            }
            methods.insert(&m.name, m.name_span);
            if index.tasks.contains_key(&m.task.name) {
                index
                    .methods_of_task
                    .entry(m.task.name.clone())
                    .or_default()
                    .push(i);
            } else {
                let mut diag = Diagnostic::error(
                    m.task.span,
                    format!(
                        "method `{}` is for undeclared task `{}`",
                        m.name, m.task.name
                    ),
                );
                if index.functionalities.contains_key(&m.task.name) {
                    diag = diag.with_note("that is a functionality; methods decompose tasks");
                } else {
                    diag = diag.with_note(format!(
                        "declare it with `(:task {} :parameters (...))`",
                        m.task.name
                    ));
                }
                self.diags.push(diag);
            }
        }
        for (i, a) in domain.actions.iter().enumerate() {
            match domain.actions[..i].iter().find(|b| b.name == a.name) {
                Some(first) => self.duplicate("action", &a.name, a.name_span, first.name_span),
                None => {
                    index.actions.insert(a.name.clone(), i);
                }
            }
        }
        for (list, what) in [
            (&domain.predicates, "predicate"),
            (&domain.functions, "function"),
        ] {
            for (i, p) in list.iter().enumerate() {
                if let Some(first) = list[..i].iter().find(|q| q.name == p.name) {
                    self.duplicate(what, &p.name, p.span, first.span);
                }
            }
        }
        for (i, t) in domain.types.iter().enumerate() {
            if let Some(first) = domain.types[..i].iter().find(|u| u.name == t.name) {
                self.diags.push(
                    Diagnostic::error(
                        t.span,
                        format!(
                            "type `{}` is listed under two parents, `{}` and `{}`",
                            t.name, first.parent, t.parent
                        ),
                    )
                    .with_secondary(first.span, "first listed here")
                    .with_note("a type has one parent (besides `object`)"),
                );
            }
        }
        self.unique_params(&domain.constants, "`:constants`");
        index
    }

    fn unique_params(&mut self, params: &[Param], what: &str) {
        for (i, p) in params.iter().enumerate() {
            if let Some(first) = params[..i].iter().find(|q| q.name == p.name) {
                self.diags.push(
                    Diagnostic::error(
                        p.span,
                        format!("duplicate parameter `{}` in {what}", p.name),
                    )
                    .with_secondary(first.span, "first declared here"),
                );
            }
        }
    }

    fn vars_declared(&mut self, terms: &[Term], span: Span, declared: &HashSet<&str>, what: &str) {
        for term in terms {
            if let Term::Var(var) = term
                && !declared.contains(&**var)
            {
                self.diags.push(
                    Diagnostic::error(
                        span,
                        format!("variable `?{var}` is not a parameter of {what}"),
                    )
                    .with_note("declare it in `:parameters`"),
                );
            }
        }
    }

    fn literal_vars(&mut self, literals: &[Literal], declared: &HashSet<&str>, what: &str) {
        for literal in literals {
            let terms: Vec<Term> = literal.terms().cloned().collect();
            self.vars_declared(&terms, literal.span(), declared, what);
        }
    }

    /// Arity of ecology-state and declared predicates; `world` says whether the
    /// literal is about the world (actions) rather than the ecology state.
    fn predicate_arity(&mut self, domain: &Domain, atom: &Atom, world: bool) {
        let declared = domain
            .predicates
            .iter()
            .find(|p| p.name == atom.predicate)
            .map(|p| p.params.len());
        let known = declared.or_else(|| {
            ECOLOGY_PREDICATES
                .iter()
                .find(|(name, _)| *name == &*atom.predicate)
                .map(|&(_, arity)| arity)
        });
        match known {
            Some(arity) if arity != atom.args.len() => {
                self.error(
                    atom.span,
                    format!(
                        "wrong arity: `{}` takes {arity} argument{}, given {}",
                        atom.predicate,
                        plural(arity),
                        atom.args.len()
                    ),
                );
            }
            None if world && !domain.predicates.is_empty() => {
                self.diags.push(
                    Diagnostic::error(atom.span, format!("unknown predicate `{}`", atom.predicate))
                        .with_note("declare it in `(:predicates ...)`"),
                );
            }
            _ => {}
        }
    }

    fn literal_arities(&mut self, domain: &Domain, literals: &[Literal], world: bool) {
        for literal in literals {
            if let Literal::Pos(atom) | Literal::Neg(atom) = literal {
                self.predicate_arity(domain, atom, world);
            }
        }
    }

    fn functionality(&mut self, domain: &Domain, f: &Functionality) {
        let what = format!("functionality `{}`", f.name);
        self.unique_params(&f.params, &what);
        let params = names(&f.params);
        for var in [&f.component.0, &f.component.1] {
            if !var.is_empty() && !params.contains(&**var) {
                self.diags.push(
                    Diagnostic::error(
                        f.name_span,
                        format!("`:component` names `?{var}`, which is not a parameter of {what}"),
                    )
                    .with_note("`:component (?p ?c)` names the parameters bound to the PEIS and its component"),
                );
            }
        }
        self.literal_vars(&f.precondition, &params, &what);
        self.literal_vars(&f.postcondition, &params, &what);
        self.literal_arities(domain, &f.precondition, false);
        for info in f.inputs.iter().chain(&f.outputs) {
            self.vars_declared(&info.args, info.span, &params, &what);
        }
        for (i, info) in f.inputs.iter().enumerate() {
            if f.inputs[..i]
                .iter()
                .any(|o| o.name == info.name && o.args == info.args)
            {
                self.error(info.span, format!("duplicate input {info} in {what}"));
            }
        }
        for (i, info) in f.outputs.iter().enumerate() {
            if f.outputs[..i]
                .iter()
                .any(|o| o.name == info.name && o.args == info.args)
            {
                self.error(info.span, format!("duplicate output {info} in {what}"));
            }
        }
    }

    fn callee<'a>(&mut self, domain: &'a Domain, call: &Call) -> Option<Callee<'a>> {
        let (callee, params) = if let Some(f) = domain.functionality(&call.name) {
            (Callee::Functionality(f), &f.params)
        } else if let Some(t) = domain.task(&call.name) {
            (Callee::Task(t), &t.params)
        } else {
            self.diags.push(
                Diagnostic::error(
                    call.span,
                    format!("unknown task or functionality `{}`", call.name),
                )
                .with_label("no `(:task ...)` or `(:functionality ...)` has this name"),
            );
            return None;
        };
        if params.len() != call.args.len() {
            self.error(
                call.span,
                format!(
                    "wrong arity: `{}` takes {} argument{}, given {}",
                    call.name,
                    params.len(),
                    plural(params.len()),
                    call.args.len()
                ),
            );
            return None;
        }
        Some(callee)
    }

    fn method(&mut self, domain: &Domain, m: &Method) {
        let what = format!("method `{}`", m.name);
        self.unique_params(&m.params, &what);
        let params = names(&m.params);
        self.vars_declared(&m.task.args, m.task.span, &params, &what);
        self.method_task_arity(domain, m);
        self.literal_vars(&m.precondition, &params, &what);
        self.literal_arities(domain, &m.precondition, false);
        let mut unbound = Unbound::new(m, params);
        for literal in &m.precondition {
            if !matches!(literal, Literal::Pos(_)) {
                let terms: Vec<Term> = literal.terms().cloned().collect();
                unbound.check(self, &terms, literal.span());
            }
        }
        let callees = self.method_subtasks(domain, m, &what, &mut unbound);
        self.method_channels(domain, m, &what, &mut unbound, &callees);
        self.method_redirects(domain, m, &what, &mut unbound, &callees);
        self.method_interface(domain, m);
    }

    /// The method's task is called with as many arguments as it takes.
    fn method_task_arity(&mut self, domain: &Domain, m: &Method) {
        if let Some(task) = domain.task(&m.task.name)
            && task.params.len() != m.task.args.len()
        {
            self.error(
                m.task.span,
                format!(
                    "wrong arity: task `{}` takes {} argument{}, given {}",
                    task.name,
                    task.params.len(),
                    plural(task.params.len()),
                    m.task.args.len()
                ),
            );
        }
    }

    /// Labels are unique and subtasks call what exists with bound variables;
    /// returns the callee of each label (`None`: unknown).
    fn method_subtasks<'a>(
        &mut self,
        domain: &'a Domain,
        m: &'a Method,
        what: &str,
        unbound: &mut Unbound<'_>,
    ) -> HashMap<&'a str, Option<Callee<'a>>> {
        let mut callees: HashMap<&str, Option<Callee>> = HashMap::new();
        for (i, sub) in m.subtasks.iter().enumerate() {
            if let Some(first) = m.subtasks[..i].iter().find(|s| s.label == sub.label) {
                self.diags.push(
                    Diagnostic::error(
                        sub.span,
                        format!("duplicate label `{}` in {what}", sub.label),
                    )
                    .with_secondary(first.span, "first used here"),
                );
                continue;
            }
            unbound.terms(self, &sub.call.args, sub.call.span, what);
            let callee = self.callee(domain, &sub.call);
            callees.insert(&sub.label, callee);
        }
        callees
    }

    /// Each channel joins two different labelled subtasks that produce and consume its information.
    fn method_channels<'a>(
        &mut self,
        domain: &Domain,
        m: &'a Method,
        what: &str,
        unbound: &mut Unbound<'_>,
        callees: &HashMap<&str, Option<Callee<'a>>>,
    ) {
        for channel in &m.channels {
            unbound.terms(self, &channel.info.args, channel.info.span, what);
            let from = self.label(m, &channel.from, channel.span, callees);
            let to = self.label(m, &channel.to, channel.span, callees);
            if channel.from == channel.to {
                self.error(channel.span, "a channel from a subtask to itself");
                continue;
            }
            if let Some((callee, call)) = from {
                self.carries(domain, callee, call, &channel.info, Direction::Output);
            }
            if let Some((callee, call)) = to {
                self.carries(domain, callee, call, &channel.info, Direction::Input);
            }
        }
    }

    /// Each `:inputs`/`:outputs` redirect names a subtask that carries its information.
    fn method_redirects<'a>(
        &mut self,
        domain: &Domain,
        m: &'a Method,
        what: &str,
        unbound: &mut Unbound<'_>,
        callees: &HashMap<&str, Option<Callee<'a>>>,
    ) {
        for (redirects, direction) in [
            (&m.inputs, Direction::Input),
            (&m.outputs, Direction::Output),
        ] {
            for redirect in redirects {
                unbound.terms(self, &redirect.info.args, redirect.info.span, what);
                if let Some((callee, call)) = self.label(m, &redirect.label, redirect.span, callees)
                {
                    self.carries(domain, callee, call, &redirect.info, direction);
                }
            }
        }
    }

    /// A task that declares its inputs and outputs holds every method to them.
    fn method_interface(&mut self, domain: &Domain, m: &Method) {
        let Some(task) = domain.task(&m.task.name) else {
            return;
        };
        let subst: HashMap<&str, &Term> = task
            .params
            .iter()
            .map(|p| &*p.name)
            .zip(&m.task.args)
            .collect();
        for (declared, provided, word) in [
            (&task.outputs, &m.outputs, "output"),
            (&task.inputs, &m.inputs, "input"),
        ] {
            for info in declared {
                let wanted = substitute(&info.args, &subst);
                if !provided
                    .iter()
                    .any(|r| r.info.name == info.name && compatible(&r.info.args, &wanted))
                {
                    self.diags.push(
                        Diagnostic::error(
                            m.name_span,
                            format!(
                                "method `{}` does not say which subtask handles {word} {info} of task `{}`",
                                m.name, task.name
                            ),
                        )
                        .with_secondary(info.span, "declared here")
                        .with_note(format!("add `:{word}s ((({} ...) LABEL))`", info.name)),
                    );
                }
            }
        }
    }

    fn label<'a>(
        &mut self,
        m: &'a Method,
        label: &str,
        span: Span,
        callees: &HashMap<&str, Option<Callee<'a>>>,
    ) -> Option<(Callee<'a>, &'a Call)>
    where
        'a: 'a,
    {
        match m.subtask(label) {
            None => {
                let labels: Vec<&str> = m.subtasks.iter().map(|s| &*s.label).collect();
                self.diags.push(
                    Diagnostic::error(
                        span,
                        format!("no subtask labelled `{label}` in method `{}`", m.name),
                    )
                    .with_note(format!("labels: {}", labels.join(" "))),
                );
                None
            }
            Some(sub) => callees
                .get(label)
                .copied()
                .flatten()
                .map(|c| (c, &sub.call)),
        }
    }

    /// Checks that the subtask `call` has an input or output matching `info`.
    fn carries(
        &mut self,
        domain: &Domain,
        callee: Callee<'_>,
        call: &Call,
        info: &Info,
        direction: Direction,
    ) {
        let (params, declared): (&[Param], Vec<&Info>) = match (callee, direction) {
            (Callee::Functionality(f), Direction::Input) => (&f.params, f.inputs.iter().collect()),
            (Callee::Functionality(f), Direction::Output) => {
                (&f.params, f.outputs.iter().collect())
            }
            (Callee::Task(t), direction) => {
                let declared = match direction {
                    Direction::Input => &t.inputs,
                    Direction::Output => &t.outputs,
                };
                if declared.is_empty() {
                    // Undeclared task interfaces are whatever its methods redirect.
                    let any = domain.methods_of(&t.name).any(|m| {
                        let redirects = match direction {
                            Direction::Input => &m.inputs,
                            Direction::Output => &m.outputs,
                        };
                        redirects.iter().any(|r| {
                            r.info.name == info.name && r.info.args.len() == info.args.len()
                        })
                    });
                    if !any {
                        self.not_carried(call, info, direction);
                    }
                    return;
                }
                (&t.params, declared.iter().collect())
            }
        };
        let subst: HashMap<&str, &Term> = params.iter().map(|p| &*p.name).zip(&call.args).collect();
        let found = declared
            .iter()
            .any(|d| d.name == info.name && compatible(&substitute(&d.args, &subst), &info.args));
        if !found {
            self.not_carried(call, info, direction);
        }
    }

    fn not_carried(&mut self, call: &Call, info: &Info, direction: Direction) {
        let word = match direction {
            Direction::Input => "input",
            Direction::Output => "output",
        };
        self.diags.push(
            Diagnostic::error(info.span, format!("`{}` does not {word} {info}", call.name))
                .with_secondary(call.span, format!("the {word}ting subtask")),
        );
    }

    fn action(&mut self, domain: &Domain, a: &Action) {
        let what = format!("action `{}`", a.name);
        self.unique_params(&a.params, &what);
        let params = names(&a.params);
        if domain.requires("typing") || !domain.types.is_empty() {
            for p in &a.params {
                if let Some(ty) = &p.ty
                    && &**ty != "object"
                    && !domain.types.iter().any(|t| t.name == *ty)
                {
                    self.error(p.span, format!("unknown type `{ty}`"));
                }
            }
        }
        for literals in std::iter::once(&a.precondition).chain(&a.alternatives) {
            self.literal_vars(literals, &params, &what);
            self.literal_arities(domain, literals, true);
        }
        for when in &a.conditional {
            self.literal_vars(&when.condition, &params, &what);
            self.literal_arities(domain, &when.condition, true);
        }
        let conditional = a.conditional.iter().flat_map(|c| &c.effects);
        for effect in a.effects.iter().chain(conditional) {
            match effect {
                Effect::Add(atom) | Effect::Del(atom) => {
                    self.vars_declared(&atom.args, atom.span, &params, &what);
                    self.predicate_arity(domain, atom, true);
                }
                Effect::IncreaseCost(NumExpr::Function(call), _) => {
                    self.vars_declared(&call.args, call.span, &params, &what);
                    match domain.functions.iter().find(|f| f.name == call.name) {
                        None => self.error(call.span, format!("unknown function `{}`", call.name)),
                        Some(f) if f.params.len() != call.args.len() => self.error(
                            call.span,
                            format!(
                                "wrong arity: `{}` takes {} argument{}, given {}",
                                call.name,
                                f.params.len(),
                                plural(f.params.len()),
                                call.args.len()
                            ),
                        ),
                        Some(_) => {}
                    }
                }
                Effect::IncreaseCost(NumExpr::Number(_), _) => {}
            }
        }
        if let Some(goal) = &a.configure {
            self.vars_declared(&goal.args, goal.span, &params, &what);
            self.callee(domain, goal);
        }
    }

    /// Reports every task that can reach itself through its methods.
    fn recursion(&mut self, domain: &Domain) {
        // Depth-first search over task → method → subtask task, with colours.
        #[derive(Clone, Copy, PartialEq)]
        enum Colour {
            White,
            Grey,
            Black,
        }
        let mut colour = vec![Colour::White; domain.tasks.len()];
        // The path: (task index, method index, subtask index) edges taken.
        let mut reported: HashSet<usize> = HashSet::new();
        for root in 0..domain.tasks.len() {
            if colour[root] != Colour::White {
                continue;
            }
            let mut stack: Vec<Frame> = Vec::new();
            let edges = |t: usize| -> Vec<(usize, usize)> {
                let task = &domain.tasks[t];
                let mut out = Vec::new();
                for m in domain
                    .index
                    .methods_of_task
                    .get(&task.name)
                    .into_iter()
                    .flatten()
                {
                    for (s, sub) in domain.methods[*m].subtasks.iter().enumerate() {
                        if domain.index.tasks.contains_key(&sub.call.name) {
                            out.push((*m, s));
                        }
                    }
                }
                out
            };
            colour[root] = Colour::Grey;
            stack.push((root, edges(root), 0));
            while let Some((task, edges_of, next)) = stack.last_mut() {
                let task = *task;
                if *next == edges_of.len() {
                    colour[task] = Colour::Black;
                    stack.pop();
                    continue;
                }
                let (m, s) = edges_of[*next];
                *next += 1;
                let sub = &domain.methods[m].subtasks[s];
                let target = domain.index.tasks[&sub.call.name];
                match colour[target] {
                    Colour::White => {
                        colour[target] = Colour::Grey;
                        let e = edges(target);
                        stack.push((target, e, 0));
                    }
                    Colour::Grey => {
                        let start = stack.iter().position(|(t, _, _)| *t == target).unwrap_or(0);
                        let mut path: Vec<String> = Vec::new();
                        for (t, edges_of, next) in &stack[start..] {
                            let (m, _) = edges_of[next - 1];
                            path.push(format!(
                                "{} → {}",
                                domain.tasks[*t].name, domain.methods[m].name
                            ));
                        }
                        path.push(domain.tasks[target].name.to_string());
                        if reported.insert(target) {
                            self.diags.push(
                                Diagnostic::error(
                                    sub.call.span,
                                    format!(
                                        "recursive decomposition: task `{}` can reach itself through its methods",
                                        domain.tasks[target].name
                                    ),
                                )
                                .with_note(path.join(" → "))
                                .with_note("a configuration is finite; break the cycle"),
                            );
                        }
                    }
                    Colour::Black => {}
                }
            }
        }
    }
}

/// A task on the recursion search's path: the task, its (method, subtask)
/// edges, and the next edge to follow.
type Frame = (usize, Vec<(usize, usize)>, usize);

#[derive(Clone, Copy)]
enum Direction {
    Input,
    Output,
}

/// Replaces the variables of `terms` by what `subst` maps them to.
pub(crate) fn substitute(terms: &[Term], subst: &HashMap<&str, &Term>) -> Vec<Term> {
    terms
        .iter()
        .map(|t| match t {
            Term::Var(v) => subst.get(&**v).map_or_else(|| t.clone(), |&r| r.clone()),
            Term::Const(_) => t.clone(),
        })
        .collect()
}

/// Whether two argument lists could be equal once variables are bound: same
/// length, and no position with two different constants.
pub(crate) fn compatible(a: &[Term], b: &[Term]) -> bool {
    a.len() == b.len()
        && a.iter().zip(b).all(|pair| match pair {
            (Term::Const(x), Term::Const(y)) => x == y,
            _ => true,
        })
}

fn plural(n: usize) -> &'static str {
    if n == 1 { "" } else { "s" }
}
