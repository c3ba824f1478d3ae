from bgap.runner.numerics import command

main = command("bgap.commands.pipeline")
if __name__ == "__main__":
    main()
