//! The pickle of a PyTorch state dict (`data.pkl`), read by a machine that knows only what a
//! state dict needs: strings, numbers, tuples, dicts, the `OrderedDict`, tensor-rebuild and
//! storage classes, and the persistent ids that point at storages. Any other opcode or class is
//! refused before it is run, so a pickle can neither name code to call nor build anything but
//! data. Objects live in one arena and refer to each other by index: a memo reference copies
//! nothing, a cycle leaks nothing, and dropping nests no recursion, so the memory a pickle can
//! use is a constant times its length.

use std::collections::HashMap;

/// The tensor element types a state dict of ours, or of the reference network, holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dtype {
    F32,
    F64,
    F16,
    BF16,
}

impl Dtype {
    pub fn bytes(self) -> u64 {
        match self {
            Dtype::F64 => 8,
            Dtype::F32 => 4,
            Dtype::F16 | Dtype::BF16 => 2,
        }
    }
}

/// A storage as a persistent id names it: its record `data/<key>` holds `numel` elements.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Storage {
    pub dtype: Dtype,
    pub key: String,
    pub numel: u64,
}

/// A tensor as `_rebuild_tensor_v2` builds it: a view of `storage`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Tensor {
    pub storage: Storage,
    pub offset: u64,
    pub shape: Vec<u64>,
    pub stride: Vec<u64>,
}

/// The callables and classes a state dict's pickle may name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Global {
    OrderedDict,
    RebuildTensor,
    RebuildParameter,
    StorageType(Dtype),
}

impl Global {
    fn find(module: &str, name: &str) -> Option<Self> {
        Some(match (module, name) {
            ("collections", "OrderedDict") => Global::OrderedDict,
            ("torch._utils", "_rebuild_tensor_v2") => Global::RebuildTensor,
            ("torch._utils", "_rebuild_parameter") => Global::RebuildParameter,
            ("torch", "FloatStorage") => Global::StorageType(Dtype::F32),
            ("torch", "DoubleStorage") => Global::StorageType(Dtype::F64),
            ("torch", "HalfStorage") => Global::StorageType(Dtype::F16),
            ("torch", "BFloat16Storage") => Global::StorageType(Dtype::BF16),
            _ => return None,
        })
    }
}

type Id = usize;

#[derive(Debug)]
enum Obj {
    None,
    Bool,
    Int(i64),
    Float,
    Str(String),
    Tuple(Vec<Id>),
    Dict(Vec<(Id, Id)>),
    Global(Global),
    Storage(Storage),
    Tensor(Tensor),
}

#[derive(Debug, Clone, Copy)]
enum Item {
    Mark,
    Obj(Id),
}

/// How deep dicts may nest in the result (a checkpoint holding a state dict under a key).
const MAX_DEPTH: usize = 8;
/// Dimensions of one tensor.
const MAX_DIMS: usize = 16;

struct Machine<'a> {
    bytes: &'a [u8],
    pos: usize,
    arena: Vec<Obj>,
    stack: Vec<Item>,
    memo: HashMap<u32, Id>,
}

/// The tensors of the state dict pickled in `bytes`, with their dotted names (a dict nested
/// under a key names its tensors `key.name`), in pickle order. An error says what was refused
/// and at which byte.
pub fn read_state_dict_pickle(bytes: &[u8]) -> Result<Vec<(String, Tensor)>, String> {
    let mut m = Machine {
        bytes,
        pos: 0,
        arena: Vec::new(),
        stack: Vec::new(),
        memo: HashMap::new(),
    };
    let top = m.run()?;
    let mut out = Vec::new();
    m.collect(top, "", 0, &mut std::collections::HashSet::new(), &mut out)?;
    Ok(out)
}

impl Machine<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], String> {
        let end = self
            .pos
            .checked_add(n)
            .filter(|&e| e <= self.bytes.len())
            .ok_or_else(|| format!("the pickle ends inside an argument at byte {}", self.pos))?;
        let s = &self.bytes[self.pos..end];
        self.pos = end;
        Ok(s)
    }

    fn u8(&mut self) -> Result<u8, String> {
        Ok(self.take(1)?[0])
    }

    fn u16(&mut self) -> Result<u16, String> {
        Ok(u16::from_le_bytes(self.take(2)?.try_into().unwrap()))
    }

    fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().unwrap()))
    }

    fn u64(&mut self) -> Result<u64, String> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().unwrap()))
    }

    fn line(&mut self) -> Result<String, String> {
        let rest = &self.bytes[self.pos..];
        let end = rest
            .iter()
            .take(256)
            .position(|&b| b == b'\n')
            .ok_or_else(|| format!("a GLOBAL name at byte {} is not a short line", self.pos))?;
        let text = String::from_utf8(rest[..end].to_vec())
            .map_err(|_| format!("a GLOBAL name at byte {} is not UTF-8", self.pos))?;
        self.pos += end + 1;
        Ok(text)
    }

    fn text(&mut self, n: u64) -> Result<String, String> {
        let at = self.pos;
        let n = usize::try_from(n).map_err(|_| format!("a string at byte {at} is too long"))?;
        String::from_utf8(self.take(n)?.to_vec())
            .map_err(|_| format!("a string at byte {at} is not UTF-8"))
    }

    fn new_obj(&mut self, o: Obj) -> Id {
        self.arena.push(o);
        self.arena.len() - 1
    }

    fn push(&mut self, o: Obj) {
        let id = self.new_obj(o);
        self.stack.push(Item::Obj(id));
    }

    fn pop(&mut self) -> Result<Id, String> {
        match self.stack.pop() {
            Some(Item::Obj(id)) => Ok(id),
            Some(Item::Mark) => Err(format!("a MARK where a value was due at byte {}", self.pos)),
            None => Err(format!("the stack is empty at byte {}", self.pos)),
        }
    }

    fn top(&self) -> Result<Id, String> {
        match self.stack.last() {
            Some(Item::Obj(id)) => Ok(*id),
            _ => Err(format!("no value on the stack at byte {}", self.pos)),
        }
    }

    /// The values down to the last MARK (which is removed), bottom first.
    fn pop_to_mark(&mut self) -> Result<Vec<Id>, String> {
        let mark = self
            .stack
            .iter()
            .rposition(|i| matches!(i, Item::Mark))
            .ok_or_else(|| format!("no MARK on the stack at byte {}", self.pos))?;
        let items = self.stack.split_off(mark + 1);
        self.stack.pop();
        Ok(items
            .into_iter()
            .map(|i| match i {
                Item::Obj(id) => id,
                Item::Mark => unreachable!("the last mark is below these"),
            })
            .collect())
    }

    fn int(&self, id: Id) -> Option<i64> {
        match self.arena[id] {
            Obj::Int(v) => Some(v),
            _ => None,
        }
    }

    fn size(&self, id: Id, what: &str) -> Result<u64, String> {
        self.int(id)
            .and_then(|v| u64::try_from(v).ok())
            .ok_or_else(|| format!("{what} is not a non-negative integer"))
    }

    fn sizes(&self, id: Id, what: &str) -> Result<Vec<u64>, String> {
        match &self.arena[id] {
            Obj::Tuple(items) if items.len() <= MAX_DIMS => {
                items.iter().map(|&i| self.size(i, what)).collect()
            }
            _ => Err(format!("{what} is not a tuple of at most {MAX_DIMS} sizes")),
        }
    }

    fn set_items(&mut self, dict: Id, items: Vec<Id>) -> Result<(), String> {
        if !items.len().is_multiple_of(2) {
            return Err(format!("SETITEMS with an odd count at byte {}", self.pos));
        }
        let pairs: Vec<(Id, Id)> = items.chunks_exact(2).map(|p| (p[0], p[1])).collect();
        match &mut self.arena[dict] {
            Obj::Dict(entries) => {
                entries.extend(pairs);
                Ok(())
            }
            _ => Err(format!(
                "SETITEM on a value that is not a dict at byte {}",
                self.pos
            )),
        }
    }

    fn run(&mut self) -> Result<Id, String> {
        loop {
            let at = self.pos;
            let op = self
                .u8()
                .map_err(|_| "the pickle ends without STOP".to_string())?;
            match op {
                0x80 => {
                    let proto = self.u8()?;
                    if !(2..=5).contains(&proto) {
                        return Err(format!("pickle protocol {proto} (2 to 5 are read)"));
                    }
                }
                0x95 => {
                    self.u64()?; // FRAME: a length hint only
                }
                b'.' => return self.pop(),
                b'(' => self.stack.push(Item::Mark),
                b'N' => self.push(Obj::None),
                0x88 | 0x89 => self.push(Obj::Bool),
                b'K' => {
                    let v = self.u8()?;
                    self.push(Obj::Int(v.into()));
                }
                b'M' => {
                    let v = self.u16()?;
                    self.push(Obj::Int(v.into()));
                }
                b'J' => {
                    let v = self.u32()? as i32;
                    self.push(Obj::Int(v.into()));
                }
                0x8a => {
                    // LONG1: little-endian two's complement of n bytes; 8 at most here.
                    let n = usize::from(self.u8()?);
                    if n > 8 {
                        return Err(format!("an integer of {n} bytes at byte {at}"));
                    }
                    let bytes = self.take(n)?;
                    let fill = if bytes.last().is_some_and(|b| b & 0x80 != 0) {
                        0xff
                    } else {
                        0
                    };
                    let mut full = [fill; 8];
                    full[..n].copy_from_slice(bytes);
                    self.push(Obj::Int(i64::from_le_bytes(full)));
                }
                b'G' => {
                    self.take(8)?;
                    self.push(Obj::Float);
                }
                b'X' => {
                    let n = self.u32()?;
                    let s = self.text(n.into())?;
                    self.push(Obj::Str(s));
                }
                0x8c => {
                    let n = self.u8()?;
                    let s = self.text(n.into())?;
                    self.push(Obj::Str(s));
                }
                0x8d => {
                    let n = self.u64()?;
                    let s = self.text(n)?;
                    self.push(Obj::Str(s));
                }
                b')' => self.push(Obj::Tuple(Vec::new())),
                b'}' => self.push(Obj::Dict(Vec::new())),
                b't' => {
                    let items = self.pop_to_mark()?;
                    self.push(Obj::Tuple(items));
                }
                0x85..=0x87 => {
                    let n = usize::from(op - 0x84);
                    if self.stack.len() < n {
                        return Err(format!("TUPLE{n} on a short stack at byte {at}"));
                    }
                    let mut items = Vec::with_capacity(n);
                    for _ in 0..n {
                        items.push(self.pop()?);
                    }
                    items.reverse();
                    self.push(Obj::Tuple(items));
                }
                b'q' => {
                    let k = self.u8()?;
                    let top = self.top()?;
                    self.memo.insert(k.into(), top);
                }
                b'r' => {
                    let k = self.u32()?;
                    let top = self.top()?;
                    self.memo.insert(k, top);
                }
                0x94 => {
                    let k = self.memo.len() as u32;
                    let top = self.top()?;
                    self.memo.insert(k, top);
                }
                b'h' | b'j' => {
                    let k = if op == b'h' {
                        self.u8()?.into()
                    } else {
                        self.u32()?
                    };
                    let id = *self.memo.get(&k).ok_or_else(|| {
                        format!("memo slot {k} read before it was set (byte {at})")
                    })?;
                    self.stack.push(Item::Obj(id));
                }
                b'c' => {
                    let module = self.line()?;
                    let name = self.line()?;
                    self.global(&module, &name, at)?;
                }
                0x93 => {
                    let name = self.pop()?;
                    let module = self.pop()?;
                    let (Obj::Str(module), Obj::Str(name)) =
                        (&self.arena[module], &self.arena[name])
                    else {
                        return Err(format!("STACK_GLOBAL without two names at byte {at}"));
                    };
                    let (module, name) = (module.clone(), name.clone());
                    self.global(&module, &name, at)?;
                }
                b's' => {
                    let value = self.pop()?;
                    let key = self.pop()?;
                    let dict = self.top()?;
                    self.set_items(dict, vec![key, value])?;
                }
                b'u' => {
                    let items = self.pop_to_mark()?;
                    let dict = self.top()?;
                    self.set_items(dict, items)?;
                }
                b'b' => {
                    // BUILD on an OrderedDict sets its `_metadata` attribute: not a tensor, kept
                    // nowhere.
                    self.pop()?;
                    if !matches!(self.arena[self.top()?], Obj::Dict(_)) {
                        return Err(format!("BUILD on a value that is not a dict at byte {at}"));
                    }
                }
                b'Q' => {
                    let pid = self.pop()?;
                    let storage = self.storage(pid, at)?;
                    self.push(Obj::Storage(storage));
                }
                b'R' => {
                    let args = self.pop()?;
                    let callable = self.pop()?;
                    let result = self.call(callable, args, at)?;
                    self.push(result);
                }
                other => {
                    return Err(format!(
                        "opcode 0x{other:02x} at byte {at}, which a state dict does not use"
                    ));
                }
            }
        }
    }

    fn global(&mut self, module: &str, name: &str, at: usize) -> Result<(), String> {
        let g = Global::find(module, name).ok_or_else(|| {
            format!(
                "the pickle names {:?} at byte {at}, which a state dict of tensors does not use: refused before anything is called",
                format!("{module}.{name}")
            )
        })?;
        self.push(Obj::Global(g));
        Ok(())
    }

    /// `('storage', <storage type>, key, location, numel)`.
    fn storage(&self, pid: Id, at: usize) -> Result<Storage, String> {
        let bad = || format!("a persistent id at byte {at} is not a storage of a known type");
        let Obj::Tuple(parts) = &self.arena[pid] else {
            return Err(bad());
        };
        let [kind, ty, key, _location, numel] = parts.as_slice() else {
            return Err(bad());
        };
        match (&self.arena[*kind], &self.arena[*ty], &self.arena[*key]) {
            (Obj::Str(kind), Obj::Global(Global::StorageType(dtype)), Obj::Str(key))
                if kind == "storage" =>
            {
                if key.is_empty() || !key.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
                    return Err(format!("a storage key at byte {at} is not a plain name"));
                }
                Ok(Storage {
                    dtype: *dtype,
                    key: key.clone(),
                    numel: self.size(*numel, "a storage's element count")?,
                })
            }
            _ => Err(bad()),
        }
    }

    fn call(&mut self, callable: Id, args: Id, at: usize) -> Result<Obj, String> {
        let Obj::Tuple(args) = &self.arena[args] else {
            return Err(format!("REDUCE without an argument tuple at byte {at}"));
        };
        let args = args.clone();
        match self.arena[callable] {
            Obj::Global(Global::OrderedDict) if args.is_empty() => Ok(Obj::Dict(Vec::new())),
            Obj::Global(Global::RebuildTensor) if (6..=7).contains(&args.len()) => {
                let Obj::Storage(storage) = &self.arena[args[0]] else {
                    return Err(format!("a tensor at byte {at} is not built on a storage"));
                };
                Ok(Obj::Tensor(Tensor {
                    storage: storage.clone(),
                    offset: self.size(args[1], "a tensor's storage offset")?,
                    shape: self.sizes(args[2], "a tensor's shape")?,
                    stride: self.sizes(args[3], "a tensor's stride")?,
                }))
            }
            Obj::Global(Global::RebuildParameter) if args.len() == 3 => {
                match &self.arena[args[0]] {
                    Obj::Tensor(t) => Ok(Obj::Tensor(t.clone())),
                    _ => Err(format!("a parameter at byte {at} does not wrap a tensor")),
                }
            }
            _ => Err(format!(
                "REDUCE at byte {at} calls something other than a state dict's constructors"
            )),
        }
    }

    /// The tensors under `id`, named by their dotted keys; scalars (a checkpoint's epoch, say)
    /// are passed over. Each dict is visited once (`seen`): one met again (a cycle, or a dict
    /// shared under many keys, which could multiply the work without end) is refused, and so is
    /// nesting deeper than [`MAX_DEPTH`].
    fn collect(
        &self,
        id: Id,
        prefix: &str,
        depth: usize,
        seen: &mut std::collections::HashSet<Id>,
        out: &mut Vec<(String, Tensor)>,
    ) -> Result<(), String> {
        let Obj::Dict(entries) = &self.arena[id] else {
            return Err("the pickle holds no dict of tensors".into());
        };
        if !seen.insert(id) || depth >= MAX_DEPTH {
            return Err(format!(
                "a dict appears twice, or dicts nest more than {MAX_DEPTH} deep"
            ));
        }
        for &(k, v) in entries {
            let Obj::Str(key) = &self.arena[k] else {
                return Err("a state dict key is not a string".into());
            };
            let name = if prefix.is_empty() {
                key.clone()
            } else {
                format!("{prefix}.{key}")
            };
            match &self.arena[v] {
                Obj::Tensor(t) => out.push((name, t.clone())),
                Obj::Dict(_) => self.collect(v, &name, depth + 1, seen, out)?,
                Obj::None | Obj::Bool | Obj::Int(_) | Obj::Float | Obj::Str(_) => {}
                _ => {
                    return Err(format!(
                        "the value of {name:?} is neither a tensor nor a dict of them"
                    ));
                }
            }
        }
        Ok(())
    }
}
