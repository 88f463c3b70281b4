//! The bindings' copies of the C ABI, generated from the library's Rust definitions (the same
//! sources cbindgen reads for include/bass.h): the ctypes structs and constants of the Python
//! package (python/bass/_abi.py) and the MEX gateway's field tables (matlab/bass_mex_fields.h).
//! The structs and constants are read with `syn`; what only a binding decides (a Python class
//! name, a Matlab field name or value kind) is said once here, and a struct member without a
//! rule for it stops the generation with its name.

use std::fmt::Write as _;
use std::path::Path;

use syn::{Expr, Fields, FnArg, Item, Lit, ReturnType, Type};

/// The library's sources, in the order cbindgen.toml's header names them.
const SOURCES: [&str; 5] = ["lib.rs", "port.rs", "stream.rs", "writer.rs", "control.rs"];

/// A `#[repr(C)]` struct: its name and its members (name, Rust type as written).
struct Struct {
    name: String,
    fields: Vec<(String, Type)>,
}

/// A C function or function-pointer type: its parameters' types and its return type.
struct Signature {
    name: String,
    params: Vec<Type>,
    ret: Option<Type>,
}

/// What the library's sources define for C: structs, `pub const BASS_*` (name, value text),
/// the exported functions and the callback types.
struct Abi {
    structs: Vec<Struct>,
    consts: Vec<(String, String)>,
    functions: Vec<Signature>,
    callbacks: Vec<Signature>,
}

fn signature(name: String, inputs: impl Iterator<Item = Type>, output: &ReturnType) -> Signature {
    let ret = match output {
        ReturnType::Default => None,
        ReturnType::Type(_, t) => Some((**t).clone()),
    };
    Signature { name, params: inputs.collect(), ret }
}

fn read_abi(crate_dir: &Path) -> Abi {
    let mut abi =
        Abi { structs: Vec::new(), consts: Vec::new(), functions: Vec::new(), callbacks: Vec::new() };
    for file in SOURCES {
        let path = crate_dir.join("src").join(file);
        let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("read {}: {e}", path.display()));
        let parsed = syn::parse_file(&text).unwrap_or_else(|e| panic!("parse {}: {e}", path.display()));
        for item in parsed.items {
            match item {
                Item::Struct(s) if s.attrs.iter().any(is_repr_c) => {
                    let Fields::Named(named) = s.fields else { continue };
                    let fields = named
                        .named
                        .into_iter()
                        .map(|f| (f.ident.expect("a named field").to_string(), f.ty))
                        .collect();
                    abi.structs.push(Struct { name: s.ident.to_string(), fields });
                }
                Item::Const(c) if c.ident.to_string().starts_with("BASS_") => {
                    abi.consts.push((c.ident.to_string(), value_text(&c.expr)));
                }
                Item::Fn(f) if f.sig.abi.is_some() && f.sig.ident.to_string().starts_with("bass_") => {
                    let params = f.sig.inputs.iter().map(|a| match a {
                        FnArg::Typed(t) => (*t.ty).clone(),
                        FnArg::Receiver(_) => panic!("{}: a C function has no self", f.sig.ident),
                    });
                    abi.functions.push(signature(f.sig.ident.to_string(), params, &f.sig.output));
                }
                Item::Type(t) if t.ident.to_string().ends_with("_fn") => {
                    let Some(bare) = callback_fn(&t.ty) else { panic!("{}: not Option<extern fn>", t.ident) };
                    let params = bare.inputs.iter().map(|a| a.ty.clone());
                    abi.callbacks.push(signature(t.ident.to_string(), params, &bare.output));
                }
                _ => {}
            }
        }
    }
    abi
}

/// The `extern "C" fn` inside `Option<...>` (a nullable C function pointer).
fn callback_fn(t: &Type) -> Option<&syn::TypeBareFn> {
    let Type::Path(p) = t else { return None };
    let last = p.path.segments.last()?;
    let syn::PathArguments::AngleBracketed(args) = &last.arguments else { return None };
    match args.args.first()? {
        syn::GenericArgument::Type(Type::BareFn(f)) if last.ident == "Option" => Some(f),
        _ => None,
    }
}

fn is_repr_c(a: &syn::Attribute) -> bool {
    a.path().is_ident("repr") && a.parse_args::<syn::Ident>().is_ok_and(|i| i == "C")
}

/// A constant's value as Python and C both read it: an integer literal, `u32::MAX` or `u64::MAX`.
fn value_text(e: &Expr) -> String {
    match e {
        Expr::Lit(l) => match &l.lit {
            Lit::Int(i) => i.base10_digits().to_owned(),
            other => panic!("constant value {} is not an integer", quote::quote!(#other)),
        },
        Expr::Path(p) if quote::quote!(#p).to_string().replace(' ', "") == "u32::MAX" => u32::MAX.to_string(),
        Expr::Path(p) if quote::quote!(#p).to_string().replace(' ', "") == "u64::MAX" => u64::MAX.to_string(),
        other => panic!("constant value `{}`: teach bindings/mod.rs to read it", quote::quote!(#other)),
    }
}

fn type_text(t: &Type) -> String {
    quote::quote!(#t).to_string().replace(' ', "")
}

impl Abi {
    fn get(&self, name: &str) -> &Struct {
        self.structs.iter().find(|s| s.name == name).unwrap_or_else(|| panic!("no #[repr(C)] struct {name}"))
    }

    fn consts_with_prefix<'a>(&'a self, prefix: &'a str) -> impl Iterator<Item = (&'a str, &'a str)> + 'a {
        self.consts.iter().filter(move |(n, _)| n.starts_with(prefix)).map(|(n, v)| (n.as_str(), v.as_str()))
    }
}

/// The ctypes type of a member's, parameter's or return value's Rust type.
fn ctype(t: &Type) -> String {
    let text = type_text(t);
    if text == "bass_result" {
        return "c_int".to_owned();
    }
    if let Some(name) = text.strip_suffix("_fn").and_then(|n| n.strip_prefix("bass_")) {
        return format!("{}_FN", name.to_ascii_uppercase());
    }
    if let Some((_, class, _)) = PY_STRUCTS.iter().find(|(c, _, _)| *c == text) {
        return (*class).to_owned();
    }
    if OPAQUE.contains(&text.as_str()) || text == "c_void" {
        return "c_void".to_owned();
    }
    let scalar = |s: &str| match s {
        "u32" => Some("c_uint32"),
        "u64" => Some("c_uint64"),
        "i32" => Some("c_int32"),
        "c_int" => Some("c_int"),
        "usize" => Some("c_size_t"),
        "f64" => Some("c_double"),
        "c_char" => Some("c_char"),
        _ => None,
    };
    if let Some(c) = scalar(&text) {
        return c.to_owned();
    }
    if let Type::Array(a) = t {
        let len = type_len(&a.len);
        if type_text(&a.elem) == "c_char" {
            return format!("c_char * {len}");
        }
        return format!("{} * {len}", ctype(&a.elem));
    }
    if let Type::Ptr(p) = t {
        return match (type_text(&p.elem).as_str(), p.mutability.is_some()) {
            // A C string in; a buffer the library writes text into.
            ("c_char", false) => "c_char_p".to_owned(),
            (_, _) => match ctype(&p.elem).as_str() {
                "c_void" => "c_void_p".to_owned(),
                inner => format!("POINTER({inner})"),
            },
        };
    }
    panic!("member type `{text}`: teach bindings/mod.rs its ctypes type")
}

fn type_len(e: &Expr) -> String {
    match e {
        Expr::Path(p) => quote::quote!(#p).to_string(),
        Expr::Lit(_) => value_text(e),
        other => panic!("array length `{}`", quote::quote!(#other)),
    }
}

/// The opaque handles (a `void *` for ctypes).
const OPAQUE: [&str; 3] = ["bass_port", "bass_writer", "bass_stream"];

/// The structs the Python package mirrors: (C name, Python class, what the class is).
const PY_STRUCTS: [(&str, &str, &str); 11] = [
    ("bass_port_info", "PortInfo", "bass_port_info."),
    ("bass_chunk_info", "ChunkInfo", "bass_chunk_info."),
    ("bass_chunk_ext", "ChunkExt", "bass_chunk_ext (port format 2.4: timestamp bound, channel masks)."),
    ("bass_chunk_meta", "ChunkMeta", "bass_chunk_meta."),
    ("bass_broker_status", "Status", "bass_broker_status (the broker's answer to Status)."),
    (
        "bass_replica_info",
        "ReplicaInfo",
        "bass_replica_info (a mirror's answer about its replica and the source it follows).",
    ),
    ("bass_device_info", "DeviceInfo", "bass_device_info (one device of a several-device acquisition)."),
    ("bass_stream_config", "StreamConfig", "bass_stream_config (python/bass/stream.py)."),
    ("bass_block", "Block", "bass_block (one block of a callback stream)."),
    ("bass_stream_event", "StreamEvent", "bass_stream_event (an event of a callback stream)."),
    ("bass_view", "View", "bass_view (frames read in place in the port mapping)."),
];

/// python/bass/_abi.py.
pub fn python(crate_dir: &Path) -> String {
    let abi = read_abi(crate_dir);
    let mut py = String::from(
        "\"\"\"The C ABI of include/bass.h for ctypes: constants and structs.\n\n\
         Generated by `make header` from libbassclient/src (libbassclient/tests/bindings): do not edit.\n\
         \"\"\"\n\nimport ctypes\nfrom ctypes import POINTER, c_char, c_char_p, c_double, c_int, c_int32, c_size_t, c_uint32, c_uint64, c_void_p  # noqa: F401\n\n",
    );
    for (name, value) in &abi.consts {
        writeln!(py, "{name} = {value}").unwrap();
    }
    py.push_str(
        "\n# The BASS_CHUNK_* flags by name without the prefix, in the header's order.\nCHUNK_FLAGS = {",
    );
    let flags: Vec<String> =
        abi.consts_with_prefix("BASS_CHUNK_").map(|(n, v)| format!("\"{}\": {v}", &n[11..])).collect();
    py.push_str(&flags.join(", "));
    py.push_str("}\n\n# The BASS_STATE_* values and their names (bass_state_str's).\nSTATE_NAMES = {");
    let states: Vec<String> = abi
        .consts_with_prefix("BASS_STATE_")
        .map(|(n, v)| format!("{v}: \"{}\"", n[11..].to_ascii_lowercase()))
        .collect();
    py.push_str(&states.join(", "));
    py.push_str("}\n");
    for (cname, class, doc) in PY_STRUCTS {
        write!(py, "\n\nclass {class}(ctypes.Structure):\n    \"\"\"{doc}\"\"\"\n\n    _fields_ = [\n")
            .unwrap();
        for (field, ty) in &abi.get(cname).fields {
            writeln!(py, "        (\"{field}\", {}),", ctype(ty)).unwrap();
        }
        py.push_str("    ]\n");
    }
    py.push_str("\n\n# The callback types.\n");
    for cb in &abi.callbacks {
        writeln!(
            py,
            "{} = ctypes.CFUNCTYPE({})",
            ctype(&syn::parse_str(&cb.name).unwrap()),
            c_signature(cb).join(", ")
        )
        .unwrap();
    }
    py.push_str("\n# Every exported function: name -> (restype, argtypes).\nSIGNATURES = {\n");
    for f in &abi.functions {
        let mut sig = c_signature(f);
        let ret = sig.remove(0);
        writeln!(py, "    \"{}\": ({ret}, [{}]),", f.name, sig.join(", ")).unwrap();
    }
    py.push_str("}\n");
    py
}

/// The return type (`None` for void) then the parameter types, for ctypes.
fn c_signature(s: &Signature) -> Vec<String> {
    let ret = s.ret.as_ref().map_or("None".to_owned(), ctype);
    std::iter::once(ret).chain(s.params.iter().map(ctype)).collect()
}

/// The MEX gateway's tables: (C struct, C array name, what it is).
const MEX_TABLES: [(&str, &str, &str); 5] = [
    ("bass_port_info", "INFO_FIELDS", "bass_port_info: bass('info') and GetInfo"),
    ("bass_broker_status", "STATUS_FIELDS", "bass_broker_status: bass('status')"),
    ("bass_replica_info", "REPLICA_FIELDS", "bass_replica_info: Status's `replica` field"),
    ("bass_chunk_info", "CHUNK_FIELDS", "bass_chunk_info: bass('chunks')"),
    ("bass_device_info", "DEVICE_FIELDS", "bass_device_info: Status's `devices` field"),
];

/// Members a Matlab struct leaves out.
const MEX_SKIPPED: [&str; 1] = ["reserved"];

/// Matlab names that are not the C member in camelCase (the BASS documentation's words).
fn matlab_name(member: &str) -> String {
    match member {
        "frames_per_chunk" => "nFramesPerChunk".to_owned(),
        "chunks_on_port" => "nChunksOnPort".to_owned(),
        "frames_on_port" => "nFramesOnPort".to_owned(),
        _ => camel(member),
    }
}

fn camel(snake: &str) -> String {
    let mut words = snake.split('_');
    let mut out = words.next().unwrap_or_default().to_ascii_lowercase();
    for w in words {
        let mut c = w.chars();
        if let Some(first) = c.next() {
            out.push(first.to_ascii_uppercase());
            out.push_str(&c.as_str().to_ascii_lowercase());
        }
    }
    out
}

/// How a member becomes a Matlab value (`enum value_kind` of bass_mex_tables.h).
fn matlab_kind(member: &str, t: &Type) -> &'static str {
    match (member, type_text(t).as_str()) {
        ("state", "u32") => "AS_STATE",
        ("writer_alive" | "link_up", "u32") => "AS_LOGICAL",
        // A size, exact in a double: Matlab users index with it.
        ("frames_on_port", "u64") => "AS_DOUBLE_U64",
        (_, "u32") => "AS_DOUBLE_U32",
        (_, "u64") => "AS_UINT64",
        (_, "f64") => "AS_DOUBLE",
        (_, ty) if ty.starts_with("[c_char;") => "AS_TEXT",
        (_, ty) => panic!("member {member}: type {ty} has no Matlab kind in bindings/mod.rs"),
    }
}

/// matlab/bass_mex_fields.h.
pub fn mex(crate_dir: &Path) -> String {
    let abi = read_abi(crate_dir);
    let mut h = String::from(
        "/* Generated by `make header` from libbassclient/src (libbassclient/tests/bindings): do not edit.\n \
         * The Matlab field of every member of the structs the MEX gateway returns, in the header's\n \
         * order, and the name of every chunk flag. Included by bass_mex_tables.h. */\n\
         #ifndef BASS_MEX_FIELDS_H\n#define BASS_MEX_FIELDS_H\n",
    );
    for (cname, table, doc) in MEX_TABLES {
        write!(h, "\n/* {doc}. */\nstatic const struct field_map {table}[] = {{\n").unwrap();
        for (member, ty) in abi.get(cname).fields.iter().filter(|(m, _)| !MEX_SKIPPED.contains(&m.as_str())) {
            writeln!(
                h,
                "    FIELD({cname}, \"{}\", {member}, {}),",
                matlab_name(member),
                matlab_kind(member, ty)
            )
            .unwrap();
        }
        h.push_str("};\n");
    }
    h.push_str(
        "\n/* Every BASS_CHUNK_* flag, in the header's order: ChunkInfo adds one logical field per flag. */\n\
         static const struct {\n    uint32_t bit;\n    const char *name;\n} CHUNK_FLAGS[] = {\n",
    );
    let chunk_members: Vec<String> =
        abi.get("bass_chunk_info").fields.iter().map(|(m, _)| matlab_name(m)).collect();
    for (name, _) in abi.consts_with_prefix("BASS_CHUNK_") {
        let field = camel(&name[11..]);
        assert!(!chunk_members.contains(&field), "flag {name}'s Matlab field {field} would hide a member");
        writeln!(h, "    {{{name}, \"{field}\"}},").unwrap();
    }
    h.push_str("};\n\n#endif\n");
    h
}
