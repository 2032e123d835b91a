// The job options the CLI and the Python package expose, as one table per job message keyed by the proto field each
// sets: the proto (surfacer.v1.JobSpec) is the option model, and flags and keywords are derived from its field names.
//
//   path "min_angle_degrees"  ->  CLI --min-angle-degrees, Python min_angle_degrees=
//   path "container.box"      ->  CLI --container-box,     Python container_box=
//
// A field's `aliases` are older or shorter spellings that stay accepted (in CLI form: "min-angle" is --min-angle and
// min_angle=). A shorthand (`parts`) sets several fields from one list: --sweeps 5,15,5 sets laplacian_sweeps,
// bilaplacian_sweeps and polish_sweeps; --flows d,n sets d_flow and n_flow on and t_flow off.
//
// Values are written as text in every front end (Python values are formatted first): numbers, whole numbers, bools
// (a CLI flag sets true), enums by their short lower-case names ("tiles" for POLYGONIZER_TILES), Bounds as
// x0,y0,z0,x1,y1,z1 and Vec3 as x,y,z. Only the syntax is checked here. Ranges, defaults and what is required are
// core's, checked through wire::check_job_options() by the client exactly as the server checks them, and an error
// there is reported under the spelling the user gave (name_of_field).
#pragma once

#include <functional>
#include <map>
#include <string>
#include <utility>
#include <vector>

namespace google::protobuf {
class Message;
}  // namespace google::protobuf

namespace surfacer::v1 {
class JobSpec;
}  // namespace surfacer::v1

namespace surfacer::client {

// The job messages with options, as the CLI's subcommands name them; the active job's common fields (kActive) sit
// beside the fields of its mode; kOutput is spec.output (surfacer.v1.OutputOptions), every job type's.
enum class JobTable { kIsosurface, kParticles, kOptimize, kActive, kCoat, kMorph, kAdvect, kOutput };

struct JobField {
  // The field below the table's message ("r_inner", "polygonize.cells"); for a shorthand, its own name.
  std::string path;
  // The spelling when the path's own would be ambiguous within a command (the velocity grid's "grid.spacing" beside
  // the active job's grid_spacing is --velocity-spacing); empty: the path's.
  std::string name = "";
  std::string help = "";
  std::string value_name = "";  // --help's placeholder ("R", "BOX"); empty for a bool, which is a flag on the CLI
  // Older spellings still accepted, CLI form without the dashes ("min-angle").
  std::vector<std::string> aliases = {};
  // The engine's own default, as --help prints it; unset when the help says it in words.
  std::function<std::string()> default_value = {};
  // A shorthand: the fields it sets, positionally from a comma-separated list (`member_set` false: "5,15,5"), or as a
  // set of names (`member_set` true: each field's name is its first letter, listed ones true, the others false).
  std::vector<std::string> parts = {};
  bool member_set = false;
  // For an enum field, words accepted beside the values' own short names, each {word, short name}: encoding's "raw"
  // for "ply". Listed in errors and in the Python annotation.
  std::vector<std::pair<std::string, std::string>> words = {};
};

// The fields of `table`, in --help order.
const std::vector<JobField>& job_fields(JobTable table);
// The field of `table` at `path` ("encoding"); throws std::logic_error when the table has none.
const JobField& job_field(JobTable table, const std::string& path);
// The field's own spelling: `name`, else `path` ("container.box").
std::string spelling(const JobField& field);

// Where `table`'s message sits in a JobSpec ("spec.particles", "spec.active.coat"), and that message in `spec`
// (created, which also selects the job type and the active mode).
std::string table_path(JobTable table);
google::protobuf::Message& table_message(v1::JobSpec& spec, JobTable table);

// Whether `field` (one of `table`'s) takes words rather than numbers: an enum ("tiles") or a set of names ("d,n").
bool takes_words(JobTable table, const JobField& field);

// The annotation of `field`'s Python keyword in the package's type stubs, from its proto type: "float", "int", "bool",
// Literal["tiles", "cubes"] for an enum, "Sequence[float]" for Bounds and Vec3, "Sequence[int]" for a shorthand of
// whole numbers, "Union[str, Sequence[str]]" for a set of names or a repeated string field.
std::string python_type(JobTable table, const JobField& field);
// The CLI flag and the Python keyword of a spelling ("min_angle_degrees" or "min-angle" -> "--min-angle-degrees" /
// "--min-angle", and "min_angle_degrees" / "min_angle").
std::string cli_flag(const std::string& spelling);
std::string keyword(const std::string& spelling);

// Sets `field` (one of `table`'s) in `spec` from `text`, records `name` (the spelling the user gave: "--r-inner",
// "r_inner") as the name of every field it sets in `names` (request path -> name), and refuses a second member of a
// oneof the user has already set. Throws CliError(kUsage) naming `name` when the text is not a value of the field's
// type.
void set_job_field(v1::JobSpec& spec, JobTable table, const JobField& field, const std::string& text,
                   const std::string& name, std::map<std::string, std::string>& names);

// The name of the field at `request_path` ("spec.particles.container.box.min.x" -> "--container-box") for an error
// message: the one the user gave it (the entry of `names` for the path or its nearest enclosing field), else the
// table's own spelling (CLI form, or Python's with `python`); empty when no table has the field.
std::string name_of_field(const std::map<std::string, std::string>& names, const std::string& request_path,
                          bool python);
// The names the user gave fields at or below `request_path` ("spec.optimize.polygonize" -> "--start-cells,
// --start-method"), each once, comma-separated; empty when none.
std::string names_below(const std::map<std::string, std::string>& names, const std::string& request_path);

}  // namespace surfacer::client
